//! The scan: which points to measure, from which side, how often, and how the
//! measurements become a map.
//!
//! Design: a coarse grid over the travel (default every 10 mm) for the smooth errors and
//! the cross terms, plus one dense line along each axis through the middle of the
//! other (default every 1 mm: five points per 5 mm lead, enough for the ballscrew's
//! periodic error, which depends only on the nut's position along its own screw). Every
//! point is approached from below and then from above on both axes (backlash differs
//! per direction), and the whole plan is run `passes` times (default 2), so every node
//! carries a mean and a dispersion. On the 200 x 150 mm demo stage that is
//! (21 x 16 + 201 + 151) x 2 sides x 2 passes = 2752 frames, against 120 000 for a dense
//! 1 mm grid. Errors are stored relative to the reference point measured at the start of
//! each run, so a scan resumed after a new homing (which moves the zero by a few um)
//! joins the first part seamlessly.

use crate::{Approach, Direction};
use protocol::errormap::{ErrorMap, Grid, Identity, Line, Measured, Node, Stat, SCHEMA};
use std::collections::BTreeMap;

/// How dense and how often.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScanSpec {
    pub grid_step_mm: f64,
    pub line_step_mm: f64,
    pub passes: u32,
}

impl Default for ScanSpec {
    fn default() -> Self {
        Self {
            grid_step_mm: 10.0,
            line_step_mm: 1.0,
            passes: 2,
        }
    }
}

/// Where a measurement goes in the map.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Slot {
    Grid { i: usize, j: usize },
    XLine { k: usize },
    YLine { k: usize },
}

/// One measurement to take.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScanPoint {
    pub command_mm: [f64; 2],
    pub dir: Direction,
    pub pass: u32,
    pub slot: Slot,
}

/// The plan of a scan over `lo..hi` (machine mm).
#[derive(Clone, Debug, PartialEq)]
pub struct ScanPlan {
    pub spec: ScanSpec,
    pub xs: Vec<f64>,
    pub ys: Vec<f64>,
    /// The dense line along X sits at this Y; the one along Y at this X.
    pub x_line_at: f64,
    pub y_line_at: f64,
    pub x_line: Vec<f64>,
    pub y_line: Vec<f64>,
    pub points: Vec<ScanPoint>,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ScanError {
    #[error("the scan area {lo:?}..{hi:?} mm is empty or not finite")]
    EmptyArea { lo: [f64; 2], hi: [f64; 2] },
    #[error("{what} must be a positive number of mm at most the area's size (got {value})")]
    BadStep { what: &'static str, value: f64 },
    #[error("passes must be 1 to 10 (got {0})")]
    BadPasses(u32),
    #[error("measurement #{0} is not in the plan")]
    NotInPlan(usize),
    #[error("the plan would take {frames:.0} frames; at most {MAX_SCAN_FRAMES} are accepted (a coarser step)")]
    TooManyFrames { frames: f64 },
}

/// The most frames one scan may take (a dense 1 mm grid over the demo stage is
/// 120 000): a plan is refused past it before anything is allocated.
pub const MAX_SCAN_FRAMES: u64 = 250_000;

/// How many positions [`positions`] gives, as a float (no overflow for any step).
fn position_count(lo: f64, hi: f64, step: f64) -> f64 {
    ((hi - lo) / step).ceil().max(1.0) + 1.0
}

/// The frames a scan of `spec` over `lo..hi` takes: (grid frames, dense-line frames),
/// computed without building the plan (floats: a tiny step gives a huge number, never
/// an overflow).
pub fn frames(lo: [f64; 2], hi: [f64; 2], spec: ScanSpec) -> (f64, f64) {
    let per_point = 2.0 * f64::from(spec.passes);
    let grid = position_count(lo[0], hi[0], spec.grid_step_mm)
        * position_count(lo[1], hi[1], spec.grid_step_mm);
    let lines = position_count(lo[0], hi[0], spec.line_step_mm)
        + position_count(lo[1], hi[1], spec.line_step_mm);
    (grid * per_point, lines * per_point)
}

/// Positions from `lo` to `hi` at most `step` apart, both ends included.
fn positions(lo: f64, hi: f64, step: f64) -> Vec<f64> {
    let n = ((hi - lo) / step).ceil().max(1.0) as usize;
    (0..=n)
        .map(|k| lo + (hi - lo) * k as f64 / n as f64)
        .collect()
}

impl ScanPlan {
    pub fn new(lo: [f64; 2], hi: [f64; 2], spec: ScanSpec) -> Result<Self, ScanError> {
        if !(lo.iter().chain(&hi).all(|v| v.is_finite()) && hi[0] > lo[0] && hi[1] > lo[1]) {
            return Err(ScanError::EmptyArea { lo, hi });
        }
        let size = (hi[0] - lo[0]).min(hi[1] - lo[1]);
        for (what, v) in [
            ("the grid step", spec.grid_step_mm),
            ("the line step", spec.line_step_mm),
        ] {
            if !(v.is_finite() && v > 0.0 && v <= size) {
                return Err(ScanError::BadStep { what, value: v });
            }
        }
        if !(1..=10).contains(&spec.passes) {
            return Err(ScanError::BadPasses(spec.passes));
        }
        let (grid, lines) = frames(lo, hi, spec);
        if grid + lines > MAX_SCAN_FRAMES as f64 {
            return Err(ScanError::TooManyFrames {
                frames: grid + lines,
            });
        }
        let xs = positions(lo[0], hi[0], spec.grid_step_mm);
        let ys = positions(lo[1], hi[1], spec.grid_step_mm);
        let x_line = positions(lo[0], hi[0], spec.line_step_mm);
        let y_line = positions(lo[1], hi[1], spec.line_step_mm);
        let x_line_at = ys[ys.len() / 2];
        let y_line_at = xs[xs.len() / 2];
        let mut points = Vec::new();
        for pass in 0..spec.passes {
            let mut visit = |p: [f64; 2], slot: Slot| {
                for dir in [Direction::FORWARD, Direction::REVERSE] {
                    points.push(ScanPoint {
                        command_mm: p,
                        dir,
                        pass,
                        slot,
                    });
                }
            };
            // Serpentine over the grid: short moves between neighbours.
            for (j, &y) in ys.iter().enumerate() {
                for n in 0..xs.len() {
                    let i = if j % 2 == 0 { n } else { xs.len() - 1 - n };
                    visit([xs[i], y], Slot::Grid { i, j });
                }
            }
            for (k, &x) in x_line.iter().enumerate() {
                visit([x, x_line_at], Slot::XLine { k });
            }
            for (k, &y) in y_line.iter().enumerate() {
                visit([y_line_at, y], Slot::YLine { k });
            }
        }
        Ok(Self {
            spec,
            xs,
            ys,
            x_line_at,
            y_line_at,
            x_line,
            y_line,
            points,
        })
    }

    /// A fingerprint of the plan, so a resumed scan continues only the same plan.
    pub fn fingerprint(&self) -> String {
        format!(
            "grid {}x{} {:.4}..{:.4} x {:.4}..{:.4}, lines {} at y {:.4} and {} at x {:.4}, {} passes",
            self.xs.len(),
            self.ys.len(),
            self.xs[0],
            self.xs[self.xs.len() - 1],
            self.ys[0],
            self.ys[self.ys.len() - 1],
            self.x_line.len(),
            self.x_line_at,
            self.y_line.len(),
            self.y_line_at,
            self.spec.passes
        )
    }
}

/// One measurement: the camera's error at a plan point (relative to the reference
/// measured at the start of its run), um, and the yaw relative to it, urad.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    pub error_um: [f64; 2],
    pub yaw_urad: f64,
}

/// The journal of a scan under way, one line per sample after a header line naming
/// the plan: `{"plan": "<fingerprint>"}` then `{"i": 17, "ex": 1.2, "ey": -0.4, "yaw": 3.1}`.
/// A stopped scan resumes from it (only for the same plan); a damaged last line (the
/// process died while writing it) is ignored, any other damage refused.
pub mod journal {
    use super::{Sample, ScanPlan};

    pub fn header(plan: &ScanPlan) -> String {
        format!("{{\"plan\": {:?}}}\n", plan.fingerprint())
    }

    pub fn line(index: usize, s: &Sample) -> String {
        format!(
            "{{\"i\": {index}, \"ex\": {:?}, \"ey\": {:?}, \"yaw\": {:?}}}\n",
            s.error_um[0], s.error_um[1], s.yaw_urad
        )
    }

    /// The samples of a journal written for `plan`.
    pub fn read(plan: &ScanPlan, text: &str) -> Result<Vec<(usize, Sample)>, String> {
        let mut lines = text.lines();
        let head = lines.next().ok_or("the journal is empty")?;
        let want = header(plan);
        if head.trim_end() != want.trim_end() {
            return Err(format!(
                "the journal is of another scan plan ({head}); this one is {}",
                want.trim_end()
            ));
        }
        let all: Vec<&str> = lines.collect();
        let mut out = Vec::new();
        for (k, l) in all.iter().enumerate() {
            let parsed = parse(l).filter(|(i, _)| *i < plan.points.len());
            match parsed {
                Some(v) => out.push(v),
                // Only the last line may be cut short.
                None if k + 1 == all.len() => break,
                None => return Err(format!("journal line {}: `{l}` is not a sample", k + 2)),
            }
        }
        Ok(out)
    }

    fn parse(l: &str) -> Option<(usize, Sample)> {
        let l = l.trim().strip_prefix('{')?.strip_suffix('}')?;
        let mut i = None;
        let (mut ex, mut ey, mut yaw) = (None, None, None);
        for part in l.split(',') {
            let (k, v) = part.split_once(':')?;
            let v = v.trim();
            match k.trim().trim_matches('"') {
                "i" => i = v.parse::<usize>().ok(),
                "ex" => ex = v.parse::<f64>().ok().filter(|x| x.is_finite()),
                "ey" => ey = v.parse::<f64>().ok().filter(|x| x.is_finite()),
                "yaw" => yaw = v.parse::<f64>().ok().filter(|x| x.is_finite()),
                _ => return None,
            }
        }
        Some((
            i?,
            Sample {
                error_um: [ex?, ey?],
                yaw_urad: yaw?,
            },
        ))
    }
}

/// Collects samples by plan index and turns them into a map.
#[derive(Clone, Debug, Default)]
pub struct MapBuilder {
    samples: BTreeMap<usize, Sample>,
}

impl MapBuilder {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn record(&mut self, plan: &ScanPlan, index: usize, s: Sample) -> Result<(), ScanError> {
        if index >= plan.points.len() {
            return Err(ScanError::NotInPlan(index));
        }
        self.samples.insert(index, s);
        Ok(())
    }

    pub fn is_done(&self, index: usize) -> bool {
        self.samples.contains_key(&index)
    }

    pub fn done(&self) -> usize {
        self.samples.len()
    }

    /// The map, once every point of the plan has a sample (None before).
    #[allow(clippy::too_many_arguments)]
    pub fn finish(
        &self,
        plan: &ScanPlan,
        identity: Identity,
        version: u32,
        created: String,
        tool_offset_mm: [f64; 2],
        board_at_machine_zero_mm: [f64; 2],
        reference_mm: [f64; 2],
    ) -> Option<ErrorMap> {
        if self.samples.len() != plan.points.len() {
            return None;
        }
        // Every sample of one slot and direction, over the passes.
        let mut by: BTreeMap<(Slot, bool), Vec<Sample>> = BTreeMap::new();
        for (k, p) in plan.points.iter().enumerate() {
            let forward = p.dir.x == Approach::Forward;
            by.entry((p.slot, forward))
                .or_default()
                .push(self.samples[&k]);
        }
        let measured = |v: &[Sample]| {
            let col = |f: fn(&Sample) -> f64| {
                Stat::of(&v.iter().map(f).collect::<Vec<_>>()).expect("at least one pass")
            };
            Measured {
                ex_um: col(|s| s.error_um[0]),
                ey_um: col(|s| s.error_um[1]),
                yaw_urad: col(|s| s.yaw_urad),
            }
        };
        let node = |slot: Slot| Node {
            forward: measured(&by[&(slot, true)]),
            reverse: measured(&by[&(slot, false)]),
        };
        let nodes = (0..plan.ys.len())
            .flat_map(|j| (0..plan.xs.len()).map(move |i| Slot::Grid { i, j }))
            .map(node)
            .collect::<Vec<_>>();
        let x_nodes = (0..plan.x_line.len())
            .map(|k| node(Slot::XLine { k }))
            .collect();
        let y_nodes = (0..plan.y_line.len())
            .map(|k| node(Slot::YLine { k }))
            .collect();
        // Expanded (k = 2) uncertainty of a node's mean: the RMS over nodes of the
        // standard error of both components.
        let se2: Vec<f64> = by
            .values()
            .map(|v| {
                let m = measured(v);
                let n = f64::from(m.ex_um.n);
                (m.ex_um.sd.powi(2) + m.ey_um.sd.powi(2)) / n
            })
            .collect();
        let uncertainty_um = 2.0 * (se2.iter().sum::<f64>() / se2.len() as f64).sqrt();
        Some(ErrorMap {
            schema: SCHEMA.into(),
            version,
            created,
            identity,
            tool_offset_mm,
            board_at_machine_zero_mm,
            reference_mm,
            grid: Grid {
                xs: plan.xs.clone(),
                ys: plan.ys.clone(),
                nodes,
            },
            x_lines: vec![Line {
                at_mm: plan.x_line_at,
                positions: plan.x_line.clone(),
                nodes: x_nodes,
            }],
            y_lines: vec![Line {
                at_mm: plan.y_line_at,
                positions: plan.y_line.clone(),
                nodes: y_nodes,
            }],
            uncertainty_um,
        })
    }
}

/// The stage as it names itself, without where it is connected (a port, a bus), which
/// may change between the scan and its use.
pub fn without_link(name: &str) -> String {
    let cut = [" at /", " on ", " at "]
        .iter()
        .filter_map(|m| name.find(m))
        .min()
        .unwrap_or(name.len());
    // The GRBL driver names itself `GRBL 1.1h (GRBL at /dev/ttyUSB0)`: a bracket
    // opened before the link goes with it.
    let cut = match name[..cut].rfind(" (") {
        Some(open) if !name[open..cut].contains(')') && cut < name.len() => open,
        _ => cut,
    };
    name[..cut].trim_end().to_string()
}

/// RFC 3339 UTC time of `t` (civil date from days since 1970, Howard Hinnant's method).
pub fn rfc3339(t: std::time::SystemTime) -> String {
    let secs = t
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs()) as i64;
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}-{m:02}-{d:02}T{:02}:{:02}:{:02}Z",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::MapModel;

    #[test]
    fn the_default_plan_of_the_demo_stage_stays_under_3000_frames() {
        let plan = ScanPlan::new([0.1, 0.1], [199.9, 149.9], ScanSpec::default()).unwrap();
        assert_eq!((plan.xs.len(), plan.ys.len()), (21, 16));
        assert!(plan.xs.windows(2).all(|w| w[1] - w[0] <= 10.0));
        assert!(plan.x_line.windows(2).all(|w| w[1] - w[0] <= 1.0));
        assert_eq!(plan.points.len(), (21 * 16 + 201 + 151) * 2 * 2);
        assert!(plan.points.len() <= 3000);
        // Each point from below and from above, in that order.
        assert_eq!(plan.points[0].dir, Direction::FORWARD);
        assert_eq!(plan.points[1].dir, Direction::REVERSE);
        assert_eq!(plan.points[0].command_mm, plan.points[1].command_mm);
    }

    #[test]
    fn the_journal_round_trips_and_belongs_to_its_plan() {
        let plan = ScanPlan::new(
            [0.0, 0.0],
            [10.0, 10.0],
            ScanSpec {
                grid_step_mm: 5.0,
                line_step_mm: 5.0,
                passes: 1,
            },
        )
        .unwrap();
        let s = Sample {
            error_um: [1.25, -0.5],
            yaw_urad: 3.0,
        };
        let text = journal::header(&plan)
            + &journal::line(3, &s)
            + &journal::line(4, &s)
            + "{\"i\": 5, \"ex";
        assert_eq!(journal::read(&plan, &text).unwrap(), vec![(3, s), (4, s)]);
        let other = ScanPlan::new([0.0, 0.0], [10.0, 10.0], ScanSpec::default()).unwrap();
        assert!(journal::read(&other, &text)
            .unwrap_err()
            .contains("another scan plan"));
        let damaged = journal::header(&plan) + "garbage\n" + &journal::line(4, &s);
        assert!(journal::read(&plan, &damaged)
            .unwrap_err()
            .contains("line 2"));
    }

    #[test]
    fn bad_specs_are_refused() {
        let s = ScanSpec {
            grid_step_mm: 0.0,
            ..Default::default()
        };
        assert!(ScanPlan::new([0.0; 2], [10.0; 2], s).is_err());
        let s = ScanSpec {
            passes: 0,
            ..Default::default()
        };
        assert!(matches!(
            ScanPlan::new([0.0; 2], [10.0; 2], s),
            Err(ScanError::BadPasses(0))
        ));
        assert!(ScanPlan::new([5.0, 0.0], [5.0, 10.0], ScanSpec::default()).is_err());
    }

    #[test]
    fn samples_become_a_map_with_means_and_dispersions() {
        let spec = ScanSpec {
            grid_step_mm: 5.0,
            line_step_mm: 2.5,
            passes: 2,
        };
        let plan = ScanPlan::new([0.0, 0.0], [10.0, 10.0], spec).unwrap();
        let mut b = MapBuilder::new();
        for (k, p) in plan.points.iter().enumerate() {
            // 0.1 um/mm slope, 6 um backlash in reverse, +-0.2 um between passes.
            let back = if p.dir.x == Approach::Reverse {
                6.0
            } else {
                0.0
            };
            let wobble = if p.pass == 0 { 0.2 } else { -0.2 };
            let e = [
                0.1 * p.command_mm[0] + back + wobble,
                -0.1 * p.command_mm[1],
            ];
            b.record(
                &plan,
                k,
                Sample {
                    error_um: e,
                    yaw_urad: 0.0,
                },
            )
            .unwrap();
        }
        let id = Identity {
            machine: "m".into(),
            controller: "c".into(),
            board: "b".into(),
            certificate_sha256: String::new(),
            camera: "cam".into(),
        };
        let map = b
            .finish(&plan, id, 1, "t".into(), [0.0; 2], [5.0; 2], [0.0; 2])
            .expect("complete");
        map.check().unwrap();
        let n = map.grid.nodes[0];
        assert!((n.forward.ex_um.mean - 0.0).abs() < 1e-12);
        assert!((n.reverse.ex_um.mean - 6.0).abs() < 1e-12);
        assert!((n.forward.ex_um.sd - 0.4f64 / 2f64.sqrt()).abs() < 1e-12);
        assert!((map.uncertainty_um - 2.0 * (0.08f64 / 2.0).sqrt()).abs() < 1e-9);
        let model = MapModel::new(map);
        let e = model
            .camera_error_um([7.3, 4.1], Direction::REVERSE)
            .unwrap();
        assert!((e[0] - (0.73 + 6.0)).abs() < 1e-9 && (e[1] + 0.41).abs() < 1e-9);
        assert!(b
            .record(
                &plan,
                plan.points.len(),
                Sample {
                    error_um: [0.0; 2],
                    yaw_urad: 0.0
                }
            )
            .is_err());
    }
}
