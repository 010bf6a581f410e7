//! The map's current reference: where the machine's zero is after the latest homing,
//! relative to where it was when the map was scanned.
//!
//! A map is relative to its reference point: each homing puts the machine's zero a few
//! micrometres elsewhere (the switch's repeatability), so after every homing one frame at
//! the map's reference point says where the camera really is, and the map is shifted by
//! it ([`MapModel::rereferenced`]). This module holds that measurement as a record (the
//! front ends keep it beside the map, `MAP.reference.json`): the camera's error seen at
//! the reference point, the shift it implies, when, after which homing, at which
//! temperature, and the identity (fingerprint) of the map it belongs to, so a record of
//! another map is refused. Pure: the time is given, nothing is read or written here.
//!
//! Sign convention: `seen_um` is where the camera really is minus where it should be
//! (board coordinates, um) at the reference point, approached from below on both axes.
//! The machine's zero moved by `shift_um = seen_um - (the map's own error there)`: a
//! command now lands `shift_um` further than at the scan, so the map's error grows by it
//! everywhere and every compensated command is `shift_um` smaller. Worked example: the
//! map says +0.40 um in X at the reference point, the camera now sees +7.10 um: the zero
//! moved +6.70 um in X, and a point the map commanded at X 50.0120 is now commanded at
//! X 50.0053.

use crate::{Direction, MapModel, ModelError};
use protocol::errormap::ErrorMap;
use serde::{Deserialize, Serialize};

/// The schema of a reference record.
pub const SCHEMA: &str = "xy-gateway/map-reference/1";

/// The largest machine-zero shift a reference accepts, um. Homing moves the zero by a
/// few um; more than half a millimetre is not a homing error but the wrong lattice
/// point, a moved board or a crash.
pub const MAX_SHIFT_UM: f64 = 500.0;

/// Which map a record belongs to.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MapId {
    /// [`fingerprint`] of the map.
    pub fingerprint: String,
    /// The map's creation time and version, for people.
    pub created: String,
    pub version: u32,
}

/// One reference measurement, as kept beside the map.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MapReference {
    pub schema: String,
    pub map: MapId,
    /// The map's reference point, machine mm.
    pub reference_mm: [f64; 2],
    /// When it was measured: RFC 3339 UTC, and the same as seconds since 1970.
    pub measured_at: String,
    pub measured_unix_s: u64,
    /// The camera's error at the reference point (observed - nominal), um.
    pub seen_um: [f64; 2],
    /// The machine zero's shift since the scan, um (`seen_um` minus the map's error
    /// there): what the map is shifted by.
    pub shift_um: [f64; 2],
    /// The controller's homing count, when it reports one.
    pub homing_count: Option<u64>,
    /// References of this map so far, this one included.
    pub reference_count: u64,
    /// The machine's temperature, when known, degrees C.
    pub temperature_c: Option<f64>,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ReferenceError {
    #[error("the machine's zero moved by ({:+.2}, {:+.2}) um, more than the {bound_um} um a homing can: the camera is on another board point (or the board or camera moved); nothing recorded", shift_um[0], shift_um[1])]
    TooLarge { shift_um: [f64; 2], bound_um: f64 },
    #[error("the reference belongs to another map (map {theirs}, this one {ours}); take a new reference (gateway reference)")]
    OtherMap { theirs: String, ours: String },
    #[error("not a reference record: {0}")]
    Invalid(String),
    #[error(transparent)]
    Model(#[from] ModelError),
}

/// The map's identity as a reference names it: FNV-1a (64 bit) over the map's JSON, so
/// any change to the map (a new scan, an edit) gives another fingerprint.
pub fn fingerprint(map: &ErrorMap) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in map.to_json().bytes() {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    format!("fnv1a64:{h:016x}")
}

/// What a reference measurement records, besides the map and the camera's error.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Circumstances {
    pub measured_at: String,
    pub measured_unix_s: u64,
    pub homing_count: Option<u64>,
    pub temperature_c: Option<f64>,
    /// The record it replaces (its count goes on).
    pub previous_count: u64,
}

impl MapReference {
    /// The record of `seen_um` measured at `map`'s reference point; refused when the
    /// shift passes `bound_um` (at most [`MAX_SHIFT_UM`]).
    pub fn new(
        map: &ErrorMap,
        seen_um: [f64; 2],
        bound_um: f64,
        at: Circumstances,
    ) -> Result<Self, ReferenceError> {
        let model = MapModel::new(map.clone());
        let mapped = model.camera_error_um(map.reference_mm, Direction::FORWARD)?;
        let shift_um = [seen_um[0] - mapped[0], seen_um[1] - mapped[1]];
        check_shift(shift_um, bound_um)?;
        Ok(Self {
            schema: SCHEMA.into(),
            map: MapId {
                fingerprint: fingerprint(map),
                created: map.created.clone(),
                version: map.version,
            },
            reference_mm: map.reference_mm,
            measured_at: at.measured_at,
            measured_unix_s: at.measured_unix_s,
            seen_um,
            shift_um,
            homing_count: at.homing_count,
            reference_count: at.previous_count + 1,
            temperature_c: at.temperature_c,
        })
    }

    /// Everything a reader relies on: the schema, finite numbers, a sane shift.
    pub fn check(&self) -> Result<(), ReferenceError> {
        if self.schema != SCHEMA {
            return Err(ReferenceError::Invalid(format!(
                "schema `{}`, this gateway reads `{SCHEMA}`",
                self.schema
            )));
        }
        let numbers = self
            .seen_um
            .iter()
            .chain(&self.shift_um)
            .chain(&self.reference_mm);
        if !numbers.chain(&self.temperature_c).all(|v| v.is_finite()) {
            return Err(ReferenceError::Invalid("a number is not finite".into()));
        }
        check_shift(self.shift_um, MAX_SHIFT_UM)
    }

    /// Refused unless the record was measured for `map`.
    pub fn check_map(&self, map: &ErrorMap) -> Result<(), ReferenceError> {
        let ours = fingerprint(map);
        if self.map.fingerprint != ours || self.reference_mm != map.reference_mm {
            return Err(ReferenceError::OtherMap {
                theirs: format!("{} of {}", self.map.fingerprint, self.map.created),
                ours: format!("{ours} of {}", map.created),
            });
        }
        Ok(())
    }

    /// The map's model under this reference (checked against the map first).
    pub fn apply(&self, model: MapModel) -> Result<MapModel, ReferenceError> {
        self.check_map(model.map())?;
        Ok(model.rereferenced(self.seen_um)?)
    }

    /// Seconds since it was measured (0 for a clock behind the record's).
    pub fn age_s(&self, now_unix_s: u64) -> u64 {
        now_unix_s.saturating_sub(self.measured_unix_s)
    }

    /// What the camera sees now at the reference point minus what it saw then, um: how
    /// far the zero drifted since this reference.
    pub fn drift_um(&self, seen_now_um: [f64; 2]) -> [f64; 2] {
        [
            seen_now_um[0] - self.seen_um[0],
            seen_now_um[1] - self.seen_um[1],
        ]
    }

    /// One line for a program's header, a log or a message: which reference, how old.
    pub fn describe(&self, now_unix_s: u64) -> String {
        let mut t = format!(
            "reference #{} of {} ({} old), machine zero shift ({:+.2}, {:+.2}) um",
            self.reference_count,
            self.measured_at,
            age_text(self.age_s(now_unix_s)),
            self.shift_um[0],
            self.shift_um[1]
        );
        if let Some(h) = self.homing_count {
            t += &format!(", after homing #{h}");
        }
        if let Some(c) = self.temperature_c {
            t += &format!(", at {c:.1} C");
        }
        t
    }
}

fn check_shift(shift_um: [f64; 2], bound_um: f64) -> Result<(), ReferenceError> {
    let bound_um = bound_um.min(MAX_SHIFT_UM);
    if !(shift_um[0].hypot(shift_um[1]) <= bound_um) {
        return Err(ReferenceError::TooLarge { shift_um, bound_um });
    }
    Ok(())
}

/// A duration as people say it: `45 s`, `12 min`, `3.5 h`, `2.1 days`.
pub fn age_text(s: u64) -> String {
    match s {
        0..=119 => format!("{s} s"),
        120..=7199 => format!("{} min", s / 60),
        7200..=172_799 => format!("{:.1} h", s as f64 / 3600.0),
        _ => format!("{:.1} days", s as f64 / 86_400.0),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::errormap::{Grid, Identity, Measured, Node, Stat};

    fn map(ex_at_reference: f64) -> ErrorMap {
        let s = |mean| Stat {
            mean,
            sd: 0.0,
            n: 1,
        };
        let m = |ex| Measured {
            ex_um: s(ex),
            ey_um: s(0.0),
            yaw_urad: s(0.0),
        };
        let node = |ex| Node {
            forward: m(ex),
            reverse: m(ex),
        };
        ErrorMap {
            schema: protocol::errormap::SCHEMA.into(),
            version: 3,
            created: "2026-11-27T12:00:00Z".into(),
            identity: Identity {
                machine: "m".into(),
                controller: "c".into(),
                board: "b".into(),
                certificate_sha256: String::new(),
                camera: "k".into(),
            },
            tool_offset_mm: [0.0; 2],
            board_at_machine_zero_mm: [0.0; 2],
            reference_mm: [5.0, 5.0],
            grid: Grid {
                xs: vec![0.0, 10.0],
                ys: vec![0.0, 10.0],
                nodes: vec![node(ex_at_reference); 4],
            },
            x_lines: vec![],
            y_lines: vec![],
            uncertainty_um: 0.3,
        }
    }

    fn at(s: u64) -> Circumstances {
        Circumstances {
            measured_at: "2026-11-27T13:00:00Z".into(),
            measured_unix_s: s,
            previous_count: 1,
            ..Circumstances::default()
        }
    }

    #[test]
    fn the_shift_is_what_the_camera_sees_beyond_the_map_and_the_commands_move_against_it() {
        // The worked example of the module's documentation.
        let m = map(0.4);
        let r = MapReference::new(&m, [7.1, -8.29], MAX_SHIFT_UM, at(100)).unwrap();
        assert!((r.shift_um[0] - 6.7).abs() < 1e-9 && (r.shift_um[1] + 8.29).abs() < 1e-9);
        assert_eq!(r.reference_count, 2);
        let before = MapModel::new(m.clone())
            .command_for([5.0, 5.0], Direction::FORWARD)
            .unwrap();
        let after = r
            .apply(MapModel::new(m))
            .unwrap()
            .command_for([5.0, 5.0], Direction::FORWARD)
            .unwrap();
        assert!(((before[0] - after[0]) * 1000.0 - 6.7).abs() < 1e-6);
        assert!(((before[1] - after[1]) * 1000.0 + 8.29).abs() < 1e-6);
        assert!(
            r.describe(100 + 720).contains("(12 min old)"),
            "{}",
            r.describe(820)
        );
        assert_eq!(
            r.drift_um([7.6, -8.29]).map(|v| (v * 100.0).round()),
            [50.0, 0.0]
        );
    }

    #[test]
    fn a_reference_of_another_map_or_an_absurd_shift_is_refused() {
        let r = MapReference::new(&map(0.4), [1.0, 1.0], MAX_SHIFT_UM, at(0)).unwrap();
        r.check().unwrap();
        let e = r.apply(MapModel::new(map(0.5))).unwrap_err();
        assert!(matches!(e, ReferenceError::OtherMap { .. }), "{e}");
        let e = MapReference::new(&map(0.0), [400.0, 320.0], MAX_SHIFT_UM, at(0)).unwrap_err();
        assert!(e.to_string().contains("more than the 500 um"), "{e}");
        let e = MapReference::new(&map(0.0), [f64::NAN, 0.0], MAX_SHIFT_UM, at(0)).unwrap_err();
        assert!(matches!(e, ReferenceError::TooLarge { .. }), "{e}");
        let e = MapReference::new(&map(0.0), [30.0, 0.0], 20.0, at(0)).unwrap_err();
        assert!(e.to_string().contains("20 um"), "{e}");
        let mut bad = r.clone();
        bad.schema = "x".into();
        assert!(bad.check().is_err());
    }

    #[test]
    fn ages_read_as_people_say_them() {
        assert_eq!(age_text(45), "45 s");
        assert_eq!(age_text(720), "12 min");
        assert_eq!(age_text(3 * 3600 + 1800), "3.5 h");
        assert_eq!(age_text(3 * 86_400), "3.0 days");
    }
}
