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
//!
//! Thermal growth (issue 39): a warming screw grows in proportion to the distance from
//! its nut's home, so after the shift is cancelled at the reference point an error
//! `k (x - x_ref)` is left. A reference may measure one more point along each axis (at
//! the reference's other coordinate, as far as the map goes) and record each axis's
//! scale since the scan, `ppm`, and with the previous record of the same map (between
//! [`RATE_INTERVAL_S`] apart) its rate, `ppm_per_h`; the map is then applied with the
//! measured scale (the rate says how fast the machine is still warming; its prediction,
//! [`MapReference::predicted_scale_ppm`], held for at most [`MAX_PREDICTION_S`], is
//! not applied by default: see [`MapReference::scale_ppm`]). Worked example: the reference at X 105 sees +2.00 um, the X
//! point at X 200 sees +2.38 um where the map says +0.10 um: X grew by
//! (2.38 - 0.10 - 2.00) / 95 mm = +2.95 ppm since the scan, and a command at X 200 is
//! 0.28 um smaller than with the shift alone. Records without `scale` (before issue 39)
//! apply the shift alone, as before.

use crate::{um_text, Direction, MapModel, ModelError, MAX_SCALE_PPM};
use protocol::errormap::ErrorMap;
use serde::{Deserialize, Serialize};

/// The schema of a reference record.
pub const SCHEMA: &str = "xy-gateway/map-reference/1";

pub use crate::MAX_SHIFT_UM;

/// The most the camera's error at the reference point may be in a record, um: the map's
/// own error there (bounded at 1 mm by the map's reader) plus the largest shift.
pub const MAX_SEEN_UM: f64 = 1500.0;

/// The most references a record may count: one a minute for 1900 years. A larger count
/// is not a count (and `u64::MAX + 1` would wrap to "reference #0").
pub const MAX_REFERENCE_COUNT: u64 = 1_000_000_000;

/// How far ahead of this computer's clock a record's time may be, s: the record is
/// written on this computer or one beside it; a record from the future lies about its
/// age (the age would read "0 s").
pub const MAX_CLOCK_AHEAD_S: u64 = 300;

/// How far a record's `shift_um` may differ from its `seen_um` minus the map's own error
/// there, um: the JSON round trip of the numbers, nothing a measurement could mean.
pub const CONSISTENCY_UM: f64 = 1e-3;

/// The most an axis's scale may be in a record, ppm: 10 um per 100 mm (a steel screw
/// 8.7 K warmer than at the scan). With the prediction ([`MAX_SCALE_RATE_PPM_PER_H`]
/// for [`MAX_PREDICTION_S`]) it stays within the model's own bound, [`MAX_SCALE_PPM`].
pub const MAX_RECORDED_SCALE_PPM: f64 = 100.0;

/// The fastest an axis's scale may grow in a record, ppm per hour (a steel screw
/// warming 8.7 K an hour).
pub const MAX_SCALE_RATE_PPM_PER_H: f64 = 100.0;

/// How long after a reference its rate predicts the scale, s: past that the scale stays
/// where the prediction got to (a warm machine settles; take a new reference).
pub const MAX_PREDICTION_S: u64 = 1800;

/// A rate is taken from the previous record only when it is this far apart, s: closer,
/// the frames' noise dominates; further, the growth is not a straight line.
pub const RATE_INTERVAL_S: std::ops::RangeInclusive<u64> = 60..=7200;

/// The least distance from the reference point to an axis's scale point, mm: a frame's
/// noise (about 0.1 um) is 5 ppm over 20 mm.
pub const MIN_SCALE_BASELINE_MM: f64 = 20.0;

/// A record's temperature must be one a machine works at, degrees C.
const TEMPERATURE_C: std::ops::RangeInclusive<f64> = -50.0..=150.0;

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
    /// (Boxed, as `scale` is: a record travels in the front ends' choices beside
    /// variants of a few bytes.)
    pub map: Box<MapId>,
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
    /// Each axis's growth since the scan, when the reference measured it (issue 39;
    /// absent in older records, which apply the shift alone).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scale: Option<Box<AxisScale>>,
}

/// Each axis's length scale since the scan, measured at one more point per axis.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AxisScale {
    /// Where it was measured, machine mm: X's point at (`at_mm[0]`, the reference's Y),
    /// Y's at (the reference's X, `at_mm[1]`), each approached from below on both axes.
    pub at_mm: [f64; 2],
    /// The camera's error seen there, um: X's error at X's point, Y's at Y's.
    pub seen_um: [f64; 2],
    /// The scale, ppm (`seen` minus the map's error there minus the shift, over the
    /// distance from the reference point): positive, the axis grew.
    pub ppm: [f64; 2],
    /// How fast it changed since the previous record of the same map, ppm per hour,
    /// when that was [`RATE_INTERVAL_S`] before this one and measured a scale.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ppm_per_h: Option<[f64; 2]>,
}

impl AxisScale {
    /// The scale predicted `age_s` after it was measured: the rate held for at most
    /// [`MAX_PREDICTION_S`].
    pub fn ppm_after(&self, age_s: u64) -> [f64; 2] {
        let h = age_s.min(MAX_PREDICTION_S) as f64 / 3600.0;
        let rate = self.ppm_per_h.unwrap_or([0.0; 2]);
        [self.ppm[0] + rate[0] * h, self.ppm[1] + rate[1] * h]
    }
}

/// Where a reference measures each axis's scale on `map` (`AxisScale::at_mm`): along
/// each axis, the end of the map farther from the reference point, a grid node on the
/// dense line through the reference point when the scan made one (the map is best
/// there); X's point at the reference's Y, Y's at the reference's X. None when the map
/// does not reach [`MIN_SCALE_BASELINE_MM`] from the reference point along an axis.
pub fn scale_points_mm(map: &ErrorMap) -> Option<[f64; 2]> {
    let g = &map.grid;
    let r = map.reference_mm;
    let mut at = [0.0; 2];
    for (k, nodes) in [&g.xs, &g.ys].into_iter().enumerate() {
        let (lo, hi) = (*nodes.first()?, *nodes.last()?);
        at[k] = if hi - r[k] >= r[k] - lo { hi } else { lo };
        if !((at[k] - r[k]).abs() >= MIN_SCALE_BASELINE_MM) {
            return None;
        }
    }
    Some(at)
}

/// The scale `seen_um` at the scale points `at_mm` implies on `model`'s map after
/// `shift_um`, ppm; refused (naming `scale.at_mm`) when a point is too close to the
/// reference point or outside the map.
fn implied_ppm(
    model: &MapModel,
    shift_um: [f64; 2],
    at_mm: [f64; 2],
    seen_um: [f64; 2],
) -> Result<[f64; 2], ReferenceError> {
    let r = model.map().reference_mm;
    let mut ppm = [0.0; 2];
    for k in 0..2 {
        let baseline_mm = at_mm[k] - r[k];
        if !(baseline_mm.abs() >= MIN_SCALE_BASELINE_MM) {
            return Err(ReferenceError::Field {
                field: "scale.at_mm",
                message: format!(
                    "{} mm along {} is {} mm from the reference point, less than the {} mm \
                     a scale is measured over",
                    number_text(at_mm[k]),
                    ["X", "Y"][k],
                    number_text(baseline_mm.abs()),
                    MIN_SCALE_BASELINE_MM
                ),
            });
        }
        let mut p = r;
        p[k] = at_mm[k];
        let mapped =
            model
                .scanned_error_um(p, Direction::FORWARD)
                .map_err(|e| ReferenceError::Field {
                    field: "scale.at_mm",
                    message: e.to_string(),
                })?;
        ppm[k] = (seen_um[k] - mapped[k] - shift_um[k]) / baseline_mm * 1000.0;
    }
    Ok(ppm)
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ReferenceError {
    #[error("the machine's zero moved by ({}, {}) um, more than the {bound_um} um a homing can: the camera is on another board point (or the board or camera moved); nothing recorded", um_text(shift_um[0]), um_text(shift_um[1]))]
    TooLarge { shift_um: [f64; 2], bound_um: f64 },
    /// One field of a record is wrong: `field` names it as the JSON does.
    #[error("`{field}`: {message}; take a new reference (gateway reference)")]
    Field {
        field: &'static str,
        message: String,
    },
    #[error("`map.fingerprint`: the reference belongs to another map (map {theirs}, this one {ours}); take a new reference (gateway reference)")]
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
            map: Box::new(MapId {
                fingerprint: fingerprint(map),
                created: map.created.clone(),
                version: map.version,
            }),
            reference_mm: map.reference_mm,
            measured_at: at.measured_at,
            measured_unix_s: at.measured_unix_s,
            seen_um,
            shift_um,
            homing_count: at.homing_count,
            // A count at its bound stays there rather than wrap.
            reference_count: (at.previous_count.saturating_add(1)).min(MAX_REFERENCE_COUNT),
            temperature_c: at.temperature_c,
            scale: None,
        })
    }

    /// The same record with each axis's scale since the scan: `seen_um` is the camera's
    /// error at the scale points `at_mm` (X's error at (`at_mm[0]`, reference Y), Y's at
    /// (reference X, `at_mm[1]`), approached from below on both axes). With `previous`
    /// (the record this one replaces: of the same map, with a scale, [`RATE_INTERVAL_S`]
    /// before) the rate too. Refused, naming the field, when a point is within
    /// [`MIN_SCALE_BASELINE_MM`] of the reference point or outside the map, or the scale
    /// or rate pass their bounds.
    pub fn with_scale(
        mut self,
        map: &ErrorMap,
        at_mm: [f64; 2],
        seen_um: [f64; 2],
        previous: Option<&MapReference>,
    ) -> Result<Self, ReferenceError> {
        let model = MapModel::new(map.clone());
        let ppm = implied_ppm(&model, self.shift_um, at_mm, seen_um)?;
        let ppm_per_h = previous
            .filter(|p| p.map.fingerprint == self.map.fingerprint)
            .and_then(|p| Some((self.measured_unix_s.checked_sub(p.measured_unix_s)?, p)))
            .filter(|(dt, _)| RATE_INTERVAL_S.contains(dt))
            .and_then(|(dt, p)| {
                let before = p.scale.as_ref()?.ppm;
                let h = dt as f64 / 3600.0;
                Some([(ppm[0] - before[0]) / h, (ppm[1] - before[1]) / h])
            });
        self.scale = Some(Box::new(AxisScale {
            at_mm,
            seen_um,
            ppm,
            ppm_per_h,
        }));
        self.check()?;
        Ok(self)
    }

    /// Everything a reader relies on without the map: the schema, each number finite
    /// and within its bound, the count, and the time written twice the same way. The
    /// error names the field.
    pub fn check(&self) -> Result<(), ReferenceError> {
        if self.schema != SCHEMA {
            return Err(ReferenceError::Invalid(format!(
                "schema `{}`, this gateway reads `{SCHEMA}`",
                self.schema
            )));
        }
        let field = |field, message: String| Err(ReferenceError::Field { field, message });
        for (name, v) in [("seen_um", self.seen_um), ("shift_um", self.shift_um)] {
            if !v.iter().all(|c| c.is_finite()) {
                return field(name, format!("({}, {}) is not a number", v[0], v[1]));
            }
        }
        if !self.reference_mm.iter().all(|c| c.is_finite()) {
            return field("reference_mm", "not a number".into());
        }
        if !self.seen_um.iter().all(|c| c.abs() <= MAX_SEEN_UM) {
            let [x, y] = self.seen_um;
            return field(
                "seen_um",
                format!(
                    "({}, {}) um, more than the {MAX_SEEN_UM} um the camera can be off at the \
                     reference point (the map's own error plus the largest shift)",
                    um_text(x),
                    um_text(y)
                ),
            );
        }
        check_shift(self.shift_um, MAX_SHIFT_UM)?;
        if let Some(s) = &self.scale {
            check_scale(s)?;
        }
        if let Some(t) = self.temperature_c {
            if !TEMPERATURE_C.contains(&t) {
                return field(
                    "temperature_c",
                    format!(
                        "{} C is not a machine's temperature (-50 to 150 C)",
                        number_text(t)
                    ),
                );
            }
        }
        if !(1..=MAX_REFERENCE_COUNT).contains(&self.reference_count) {
            return field(
                "reference_count",
                format!(
                    "{} is not a count of references (1 to {MAX_REFERENCE_COUNT})",
                    self.reference_count
                ),
            );
        }
        let written = chrono::DateTime::parse_from_rfc3339(&self.measured_at)
            .map_err(|e| ReferenceError::Field {
                field: "measured_at",
                message: format!("`{}` is not an RFC 3339 time ({e})", self.measured_at),
            })?
            .timestamp();
        if u64::try_from(written).ok() != Some(self.measured_unix_s) {
            return field(
                "measured_unix_s",
                format!(
                    "{} s since 1970, but `measured_at` says {} ({written} s)",
                    self.measured_unix_s, self.measured_at
                ),
            );
        }
        Ok(())
    }

    /// Refused unless the record was measured for `map` (its fingerprint, version, date
    /// and reference point) and its shift is what its `seen_um` implies on this map.
    pub fn check_map(&self, map: &ErrorMap) -> Result<(), ReferenceError> {
        self.check_model(&MapModel::new(map.clone()))
    }

    fn check_model(&self, model: &MapModel) -> Result<(), ReferenceError> {
        let map = model.map();
        let ours = fingerprint(map);
        if self.map.fingerprint != ours {
            return Err(ReferenceError::OtherMap {
                theirs: format!("{} of {}", self.map.fingerprint, self.map.created),
                ours: format!("{ours} of {}", map.created),
            });
        }
        if self.reference_mm != map.reference_mm {
            let [x, y] = self.reference_mm;
            return Err(ReferenceError::Field {
                field: "reference_mm",
                message: format!(
                    "({}, {}) mm, but the map's reference point is ({}, {}) mm",
                    number_text(x),
                    number_text(y),
                    number_text(map.reference_mm[0]),
                    number_text(map.reference_mm[1])
                ),
            });
        }
        // The fingerprint says which map; the fields for people must say the same.
        if self.map.created != map.created {
            return Err(ReferenceError::Field {
                field: "map.created",
                message: format!(
                    "`{}`, but the map it fingerprints was created {}",
                    self.map.created, map.created
                ),
            });
        }
        if self.map.version != map.version {
            return Err(ReferenceError::Field {
                field: "map.version",
                message: format!(
                    "{}, but the map it fingerprints is version {}",
                    self.map.version, map.version
                ),
            });
        }
        // The shift applied is `seen_um` minus the map's error: the record's own
        // `shift_um` (what it prints) must be that, or the record contradicts itself.
        let [ex, ey] = model.camera_error_um(map.reference_mm, Direction::FORWARD)?;
        let [ox, oy] = model.offset_um();
        let mapped = [ex - ox, ey - oy];
        let implied = [self.seen_um[0] - mapped[0], self.seen_um[1] - mapped[1]];
        if let Some(s) = &self.scale {
            // As for the shift: the scale applied is what `scale.seen_um` implies.
            let ppm = implied_ppm(model, self.shift_um, s.at_mm, s.seen_um)?;
            let r = map.reference_mm;
            let apart_um = |k: usize| (s.ppm[k] - ppm[k]) * (s.at_mm[k] - r[k]) / 1000.0;
            if (0..2).any(|k| !(apart_um(k).abs() <= CONSISTENCY_UM)) {
                return Err(ReferenceError::Field {
                    field: "scale.ppm",
                    message: format!(
                        "({}, {}) ppm, but `scale.seen_um` minus the map's own error there \
                         and the shift is ({}, {}) ppm: the record contradicts itself",
                        um_text(s.ppm[0]),
                        um_text(s.ppm[1]),
                        um_text(ppm[0]),
                        um_text(ppm[1]),
                    ),
                });
            }
        }
        if (0..2).any(|i| !((self.shift_um[i] - implied[i]).abs() <= CONSISTENCY_UM)) {
            return Err(ReferenceError::Field {
                field: "shift_um",
                message: format!(
                    "({}, {}) um, but `seen_um` ({}, {}) minus the map's own error there \
                     ({}, {}) is ({}, {}) um: the record contradicts itself",
                    um_text(self.shift_um[0]),
                    um_text(self.shift_um[1]),
                    um_text(self.seen_um[0]),
                    um_text(self.seen_um[1]),
                    um_text(mapped[0]),
                    um_text(mapped[1]),
                    um_text(implied[0]),
                    um_text(implied[1]),
                ),
            });
        }
        Ok(())
    }

    /// The map's model under this reference, at `now_unix_s` (this computer's clock):
    /// checked against the map first, and refused when it is dated more than
    /// [`MAX_CLOCK_AHEAD_S`] after now. The shift is bounded again where it is applied
    /// ([`MapModel::rereferenced`]).
    pub fn apply(&self, model: MapModel, now_unix_s: u64) -> Result<MapModel, ReferenceError> {
        self.check()?;
        self.check_model(&model)?;
        if self.measured_unix_s > now_unix_s.saturating_add(MAX_CLOCK_AHEAD_S) {
            return Err(ReferenceError::Field {
                field: "measured_at",
                message: format!(
                    "{} is {} after this computer's clock: a record from the future",
                    self.measured_at,
                    age_text(self.measured_unix_s - now_unix_s)
                ),
            });
        }
        let model = model.rereferenced(self.seen_um)?;
        Ok(model.rescaled(self.scale_ppm())?)
    }

    /// Each axis's scale since the scan as measured, ppm, what [`Self::apply`] applies;
    /// zero when none was measured. The rate is not applied: on the demo stage its
    /// prediction between references 3 to 10 minutes apart did not pay (the rate over
    /// 5 minutes carries about 20 ppm/h of the frames' noise; docs/error-map.md).
    pub fn scale_ppm(&self) -> [f64; 2] {
        self.scale.as_ref().map_or([0.0; 2], |s| s.ppm)
    }

    /// The scale the rate predicts at `now_unix_s` ([`AxisScale::ppm_after`]): for a
    /// front end that re-references often enough for the rate to pay.
    pub fn predicted_scale_ppm(&self, now_unix_s: u64) -> [f64; 2] {
        self.scale
            .as_ref()
            .map_or([0.0; 2], |s| s.ppm_after(self.age_s(now_unix_s)))
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
            "reference #{} of {} ({} old), machine zero shift ({}, {}) um",
            self.reference_count,
            self.measured_at,
            age_text(self.age_s(now_unix_s)),
            um_text(self.shift_um[0]),
            um_text(self.shift_um[1])
        );
        if let Some(s) = &self.scale {
            t += &format!(
                ", axes grown ({}, {}) ppm",
                um_text(s.ppm[0]),
                um_text(s.ppm[1])
            );
            if let Some(r) = s.ppm_per_h {
                t += &format!(" and growing ({}, {}) ppm/h", um_text(r[0]), um_text(r[1]));
            }
        }
        if let Some(h) = self.homing_count {
            t += &format!(", after homing #{h}");
        }
        if let Some(c) = self.temperature_c {
            t += &format!(", at {c:.1} C");
        }
        t
    }
}

/// Any other number in a message: as written, or the exponent for an absurd value.
fn number_text(v: f64) -> String {
    if v.abs() < 1e6 || !v.is_finite() {
        format!("{v}")
    } else {
        format!("{v:.3e}")
    }
}

fn check_scale(s: &AxisScale) -> Result<(), ReferenceError> {
    let field = |field, message: String| Err(ReferenceError::Field { field, message });
    let pair = |v: [f64; 2]| format!("({}, {})", um_text(v[0]), um_text(v[1]));
    let finite = |v: [f64; 2]| v.iter().all(|c| c.is_finite());
    if !finite(s.at_mm) {
        return field("scale.at_mm", "not a number".into());
    }
    if !s.seen_um.iter().all(|c| c.abs() <= MAX_SEEN_UM) {
        return field(
            "scale.seen_um",
            format!(
                "{} um, more than the {MAX_SEEN_UM} um the camera can be off there",
                pair(s.seen_um)
            ),
        );
    }
    if !s.ppm.iter().all(|c| c.abs() <= MAX_RECORDED_SCALE_PPM) {
        return field(
            "scale.ppm",
            format!(
                "{} ppm, more than the {MAX_RECORDED_SCALE_PPM} ppm an axis grows by \
                 warming (10 um per 100 mm)",
                pair(s.ppm)
            ),
        );
    }
    if let Some(r) = s.ppm_per_h {
        if !r.iter().all(|c| c.abs() <= MAX_SCALE_RATE_PPM_PER_H) {
            return field(
                "scale.ppm_per_h",
                format!(
                    "{} ppm/h, faster than the {MAX_SCALE_RATE_PPM_PER_H} ppm/h an axis \
                     grows by warming",
                    pair(r)
                ),
            );
        }
    }
    debug_assert!(
        MAX_RECORDED_SCALE_PPM + MAX_SCALE_RATE_PPM_PER_H * MAX_PREDICTION_S as f64 / 3600.0
            <= MAX_SCALE_PPM
    );
    Ok(())
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

    /// 2026-11-27T13:00:00Z
    const T0: u64 = 1_795_784_400;

    fn at(s: u64) -> Circumstances {
        let t = std::time::UNIX_EPOCH + std::time::Duration::from_secs(T0 + s);
        Circumstances {
            measured_at: crate::scan::rfc3339(t),
            measured_unix_s: T0 + s,
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
            .apply(MapModel::new(m), T0 + 100)
            .unwrap()
            .command_for([5.0, 5.0], Direction::FORWARD)
            .unwrap();
        assert!(((before[0] - after[0]) * 1000.0 - 6.7).abs() < 1e-6);
        assert!(((before[1] - after[1]) * 1000.0 + 8.29).abs() < 1e-6);
        assert!(
            r.describe(T0 + 100 + 720).contains("(12 min old)"),
            "{}",
            r.describe(T0 + 820)
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
        let e = r.apply(MapModel::new(map(0.5)), T0).unwrap_err();
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

    /// Issue 38: a record edited to `seen_um: [110, 0]` printed its own shift and applied
    /// another (99.5 um silently).
    #[test]
    fn a_record_whose_shift_is_not_its_seen_error_minus_the_map_is_refused_naming_the_field() {
        let m = map(0.4);
        let r = MapReference::new(&m, [7.1, -8.29], MAX_SHIFT_UM, at(0)).unwrap();
        r.apply(MapModel::new(m.clone()), T0).unwrap();
        let mut edited = r.clone();
        edited.seen_um = [110.0, 0.0];
        edited.check().unwrap();
        let e = edited.apply(MapModel::new(m.clone()), T0).unwrap_err();
        let text = e.to_string();
        assert!(
            matches!(
                e,
                ReferenceError::Field {
                    field: "shift_um",
                    ..
                }
            ),
            "{e}"
        );
        assert!(text.contains("(+109.60, +0.00) um"), "{text}");
        // A nanometre of JSON round trip is not a contradiction.
        let mut rounded = r.clone();
        rounded.shift_um[0] += 1e-4;
        rounded.apply(MapModel::new(m.clone()), T0).unwrap();
        // The fields for people must name the map the fingerprint names.
        let mut other = r.clone();
        other.map.created = "2026-11-01T00:00:00Z".into();
        let e = other.apply(MapModel::new(m.clone()), T0).unwrap_err();
        assert!(
            matches!(
                e,
                ReferenceError::Field {
                    field: "map.created",
                    ..
                }
            ),
            "{e}"
        );
        let mut moved = r.clone();
        moved.reference_mm = [5.0, 1e300];
        let e = moved.check_map(&m).unwrap_err();
        assert!(
            matches!(
                e,
                ReferenceError::Field {
                    field: "reference_mm",
                    ..
                }
            ),
            "{e}"
        );
        assert!(e.to_string().contains("(5, 1.000e300) mm"), "{e}");
        let mut other = r;
        other.map.version = 9;
        let e = other.check_map(&m).unwrap_err();
        assert!(
            matches!(
                e,
                ReferenceError::Field {
                    field: "map.version",
                    ..
                }
            ),
            "{e}"
        );
    }

    /// Issue 38: with `--max-correction-um 2000` a record applied 889 um.
    #[test]
    fn every_applied_shift_is_bounded_where_it_is_applied() {
        let m = map(0.4);
        let e = MapModel::new(m.clone())
            .rereferenced([889.0, 0.0])
            .unwrap_err();
        assert!(matches!(e, ModelError::ShiftTooLarge { .. }), "{e}");
        assert!(e.to_string().contains("(+888.60, +0.00) um"), "{e}");
        let e = MapModel::new(m.clone())
            .rereferenced([f64::NAN, 0.0])
            .unwrap_err();
        assert!(matches!(e, ModelError::ShiftTooLarge { .. }), "{e}");
        assert!(MapModel::new(m).rereferenced([400.4, 0.0]).is_ok());
    }

    #[test]
    fn a_record_from_the_future_or_with_two_different_times_is_refused() {
        let m = map(0.4);
        let r = MapReference::new(&m, [1.0, 1.0], MAX_SHIFT_UM, at(1000)).unwrap();
        // A clock a few minutes behind the record's is a clock, not a lie.
        r.apply(MapModel::new(m.clone()), T0 + 1000 - MAX_CLOCK_AHEAD_S)
            .unwrap();
        let e = r.apply(MapModel::new(m.clone()), T0).unwrap_err();
        assert!(
            matches!(
                e,
                ReferenceError::Field {
                    field: "measured_at",
                    ..
                }
            ),
            "{e}"
        );
        assert!(e.to_string().contains("16 min after"), "{e}");
        // 2100, as issue 38 tried: refused, not "(0 s old)".
        let mut late = r.clone();
        late.measured_at = "2100-01-01T00:00:00Z".into();
        late.measured_unix_s = 4_102_444_800;
        late.check().unwrap();
        assert!(late.apply(MapModel::new(m.clone()), T0).is_err());
        let mut two = r.clone();
        two.measured_unix_s += 3600;
        let e = two.check().unwrap_err();
        assert!(
            matches!(
                e,
                ReferenceError::Field {
                    field: "measured_unix_s",
                    ..
                }
            ),
            "{e}"
        );
        let mut garbled = r;
        garbled.measured_at = "yesterday".into();
        let e = garbled.check().unwrap_err();
        assert!(
            matches!(
                e,
                ReferenceError::Field {
                    field: "measured_at",
                    ..
                }
            ),
            "{e}"
        );
    }

    #[test]
    fn counts_and_temperatures_are_bounded_and_absurd_numbers_print_short() {
        let m = map(0.4);
        let r = MapReference::new(&m, [1.0, 1.0], MAX_SHIFT_UM, at(0)).unwrap();
        let mut wrapped = r.clone();
        wrapped.reference_count = u64::MAX;
        let e = wrapped.check().unwrap_err();
        assert!(
            matches!(
                e,
                ReferenceError::Field {
                    field: "reference_count",
                    ..
                }
            ),
            "{e}"
        );
        let mut zero = r.clone();
        zero.reference_count = 0;
        assert!(zero.check().is_err());
        // Continuing a record at the bound does not wrap to #0 (nor panic).
        let next = MapReference::new(
            &m,
            [1.0, 1.0],
            MAX_SHIFT_UM,
            Circumstances {
                previous_count: u64::MAX,
                ..at(0)
            },
        )
        .unwrap();
        assert_eq!(next.reference_count, MAX_REFERENCE_COUNT);
        let mut hot = r.clone();
        hot.temperature_c = Some(1e308);
        let e = hot.check().unwrap_err().to_string();
        assert!(e.contains("temperature_c") && e.len() < 200, "{e}");
        let mut far = r;
        far.seen_um = [1e308, 0.0];
        let e = far.check().unwrap_err().to_string();
        assert!(e.contains("`seen_um`") && e.contains("+1.000e308"), "{e}");
        assert!(e.len() < 300, "{e}");
        let e = MapReference::new(&m, [1e308, 0.0], MAX_SHIFT_UM, at(0)).unwrap_err();
        assert!(e.to_string().len() < 300, "{e}");
    }

    /// A map of 200 x 100 mm with no error but `ex_um` everywhere, reference (100, 50).
    fn wide_map(ex_um: f64) -> ErrorMap {
        let mut m = map(ex_um);
        m.grid.xs = vec![0.0, 100.0, 200.0];
        m.grid.ys = vec![0.0, 100.0];
        m.grid.nodes = vec![m.grid.nodes[0]; 6];
        m.reference_mm = [100.0, 50.0];
        m
    }

    /// The camera's error on a stage the map saw with `ex_um` everywhere, after the
    /// zero moved by `shift` and the axes grew by `ppm` about a home at (0, 0).
    fn grown(ex_um: f64, shift: [f64; 2], ppm: [f64; 2], p: [f64; 2]) -> [f64; 2] {
        [
            ex_um + shift[0] + ppm[0] * p[0] / 1000.0,
            shift[1] + ppm[1] * p[1] / 1000.0,
        ]
    }

    fn scaled_record(
        m: &ErrorMap,
        ppm: [f64; 2],
        s: u64,
        prev: Option<&MapReference>,
    ) -> MapReference {
        let (shift, r) = ([6.0, -4.0], m.reference_mm);
        let seen = grown(0.4, shift, ppm, r);
        let at_mm = [200.0, 100.0];
        let sx = grown(0.4, shift, ppm, [200.0, r[1]])[0];
        let sy = grown(0.4, shift, ppm, [r[0], 100.0])[1];
        MapReference::new(m, seen, MAX_SHIFT_UM, at(s))
            .unwrap()
            .with_scale(m, at_mm, [sx, sy], prev)
            .unwrap()
    }

    #[test]
    fn a_record_with_a_measured_scale_corrects_a_grown_axis_everywhere() {
        let m = wide_map(0.4);
        let ppm = [3.0, -2.0];
        let r = scaled_record(&m, ppm, 0, None);
        let s = r.scale.as_ref().unwrap();
        assert!(
            (s.ppm[0] - 3.0).abs() < 1e-9 && (s.ppm[1] + 2.0).abs() < 1e-9,
            "{s:?}"
        );
        assert_eq!(s.ppm_per_h, None);
        assert!(
            r.describe(T0).contains("axes grown (+3.00, -2.00) ppm"),
            "{}",
            r.describe(T0)
        );
        let applied = r.apply(MapModel::new(m.clone()), T0).unwrap();
        let shifted_only = MapModel::new(m.clone()).rereferenced(r.seen_um).unwrap();
        for p in [[0.0, 0.0], [200.0, 100.0], [37.0, 81.0], [100.0, 50.0]] {
            let want = grown(0.4, [6.0, -4.0], ppm, p);
            let got = applied.camera_error_um(p, Direction::FORWARD).unwrap();
            assert!(
                (got[0] - want[0]).abs() < 1e-9 && (got[1] - want[1]).abs() < 1e-9,
                "{p:?}: {got:?} {want:?}"
            );
            // The shift alone leaves the growth about the reference point.
            let left = shifted_only.camera_error_um(p, Direction::FORWARD).unwrap();
            assert!((want[0] - left[0] - 3.0 * (p[0] - 100.0) / 1000.0).abs() < 1e-9);
        }
        // The command at X 200 is 0.30 um smaller than with the shift alone.
        let c = applied
            .command_for([200.0, 50.0], Direction::FORWARD)
            .unwrap();
        let c0 = shifted_only
            .command_for([200.0, 50.0], Direction::FORWARD)
            .unwrap();
        assert!(((c0[0] - c[0]) * 1000.0 - 0.3).abs() < 1e-3, "{c:?} {c0:?}");
        // A homing after it keeps the scale.
        let before = applied.scale_ppm();
        let again = applied.rereferenced([0.0, 0.0]).unwrap();
        assert_eq!(again.scale_ppm(), before);
        assert!((before[0] - 3.0).abs() < 1e-9, "{before:?}");
    }

    #[test]
    fn the_scale_grows_at_the_rate_since_the_previous_record_for_a_bounded_time() {
        let m = wide_map(0.0);
        let first = scaled_record(&m, [1.0, 0.5], 0, None);
        // 10 min later X grew 1 ppm more, Y 0.5: 6 and 3 ppm/h.
        let second = scaled_record(&m, [2.0, 1.0], 600, Some(&first));
        let rate = second.scale.as_ref().unwrap().ppm_per_h.unwrap();
        assert!(
            (rate[0] - 6.0).abs() < 1e-6 && (rate[1] - 3.0).abs() < 1e-6,
            "{rate:?}"
        );
        let predicted = |s: u64| second.predicted_scale_ppm(T0 + 600 + s);
        assert!((predicted(0)[0] - 2.0).abs() < 1e-9 && (predicted(0)[1] - 1.0).abs() < 1e-9);
        assert!((predicted(600)[0] - 3.0).abs() < 1e-9);
        // Held past MAX_PREDICTION_S (30 min: +3 ppm on X).
        assert!((predicted(MAX_PREDICTION_S)[0] - 5.0).abs() < 1e-9);
        assert_eq!(
            predicted(MAX_PREDICTION_S),
            predicted(10 * MAX_PREDICTION_S)
        );
        let model = second.apply(MapModel::new(m.clone()), T0 + 1200).unwrap();
        // Applied as measured: the rate is for people and for a front end that wants it.
        assert!((model.scale_ppm()[0] - 2.0).abs() < 1e-9);
        assert!((second.scale_ppm()[0] - 2.0).abs() < 1e-9);
        // Too soon after, too long after, or of another map: no rate.
        for (s, prev) in [(30, &first), (7201, &first)] {
            let r = scaled_record(&m, [2.0, 1.0], s, Some(prev));
            assert_eq!(r.scale.unwrap().ppm_per_h, None, "{s}");
        }
        let mut other = first.clone();
        other.map.fingerprint = "fnv1a64:0".into();
        assert_eq!(
            scaled_record(&m, [2.0, 1.0], 600, Some(&other))
                .scale
                .unwrap()
                .ppm_per_h,
            None
        );
        // A previous record without a scale gives none either.
        let plain = MapReference::new(&m, [6.0, -4.0], MAX_SHIFT_UM, at(0)).unwrap();
        assert_eq!(
            scaled_record(&m, [2.0, 1.0], 600, Some(&plain))
                .scale
                .unwrap()
                .ppm_per_h,
            None
        );
    }

    #[test]
    fn a_record_before_issue_39_reads_and_applies_the_shift_alone() {
        let m = wide_map(0.4);
        let plain = MapReference::new(&m, [6.4, -4.0], MAX_SHIFT_UM, at(0)).unwrap();
        let text = serde_json::to_string(&plain).unwrap();
        assert!(!text.contains("scale"), "{text}");
        let read: MapReference = serde_json::from_str(&text).unwrap();
        assert_eq!(read, plain);
        let model = read.apply(MapModel::new(m.clone()), T0).unwrap();
        assert_eq!(model.scale_ppm(), [0.0; 2]);
        assert_eq!(model.offset_um(), [6.0, -4.0]);
        // And a record with one reads back the same.
        let r = scaled_record(&m, [3.0, -2.0], 0, None);
        let back: MapReference = serde_json::from_str(&serde_json::to_string(&r).unwrap()).unwrap();
        back.apply(MapModel::new(m), T0).unwrap();
        assert_eq!(back, r);
    }

    #[test]
    fn a_bad_scale_in_a_record_is_refused_naming_the_field() {
        let m = wide_map(0.4);
        let r = scaled_record(&m, [3.0, -2.0], 0, None);
        let field_of = |r: &MapReference| match r.apply(MapModel::new(m.clone()), T0) {
            Err(ReferenceError::Field { field, .. }) => field,
            other => panic!("{other:?}"),
        };
        let edit = |f: &dyn Fn(&mut AxisScale)| {
            let mut e = r.clone();
            f(e.scale.as_mut().unwrap());
            e
        };
        // Edited to apply another scale than it measured.
        assert_eq!(field_of(&edit(&|s| s.ppm[0] = 30.0)), "scale.ppm");
        assert_eq!(field_of(&edit(&|s| s.seen_um[1] += 1.0)), "scale.ppm");
        assert_eq!(field_of(&edit(&|s| s.ppm = [1e3, 0.0])), "scale.ppm");
        assert_eq!(
            field_of(&edit(&|s| s.seen_um = [f64::NAN, 0.0])),
            "scale.seen_um"
        );
        assert_eq!(
            field_of(&edit(&|s| s.at_mm = [f64::INFINITY, 0.0])),
            "scale.at_mm"
        );
        assert_eq!(field_of(&edit(&|s| s.at_mm[0] = 110.0)), "scale.at_mm");
        assert_eq!(field_of(&edit(&|s| s.at_mm[1] = 300.0)), "scale.at_mm");
        assert_eq!(
            field_of(&edit(&|s| s.ppm_per_h = Some([0.0, -500.0]))),
            "scale.ppm_per_h"
        );
        let e = edit(&|s| s.ppm = [1e300, 0.0])
            .check()
            .unwrap_err()
            .to_string();
        assert!(e.contains("`scale.ppm`") && e.len() < 300, "{e}");
        // Unknown fields inside are refused as elsewhere in the record.
        let text = serde_json::to_string(&r)
            .unwrap()
            .replace("\"ppm\":", "\"ppmm\":1,\"ppm\":");
        assert!(serde_json::from_str::<MapReference>(&text).is_err());
        // Measuring one too close to the reference point is refused as it is taken.
        let plain = MapReference::new(&m, [6.4, -4.0], MAX_SHIFT_UM, at(0)).unwrap();
        let e = plain
            .clone()
            .with_scale(&m, [105.0, 100.0], [0.0; 2], None)
            .unwrap_err();
        assert!(e.to_string().contains("less than the 20 mm"), "{e}");
        // A grown axis beyond the bound (a wrong frame) is refused, not applied.
        let e = plain
            .with_scale(&m, [200.0, 100.0], [6.4 + 20.0, -4.0], None)
            .unwrap_err();
        assert!(
            matches!(
                e,
                ReferenceError::Field {
                    field: "scale.ppm",
                    ..
                }
            ),
            "{e}"
        );
    }

    #[test]
    fn the_scale_points_are_the_far_ends_of_the_map_when_it_is_long_enough() {
        let mut m = wide_map(0.0);
        assert_eq!(scale_points_mm(&m), Some([200.0, 100.0]));
        m.reference_mm = [150.0, 60.0];
        assert_eq!(scale_points_mm(&m), Some([0.0, 0.0]));
        assert_eq!(scale_points_mm(&map(0.0)), None);
    }

    #[test]
    fn every_applied_scale_is_bounded_where_it_is_applied() {
        let e = MapModel::new(wide_map(0.0))
            .rescaled([250.0, 0.0])
            .unwrap_err();
        assert!(matches!(e, ModelError::ScaleTooLarge { .. }), "{e}");
        assert!(MapModel::new(wide_map(0.0))
            .rescaled([f64::NAN, 0.0])
            .is_err());
        assert!(MapModel::new(wide_map(0.0))
            .rescaled([-200.0, 200.0])
            .is_ok());
    }

    #[test]
    fn ages_read_as_people_say_them() {
        assert_eq!(age_text(45), "45 s");
        assert_eq!(age_text(720), "12 min");
        assert_eq!(age_text(3 * 3600 + 1800), "3.5 h");
        assert_eq!(age_text(3 * 86_400), "3.0 days");
    }
}
