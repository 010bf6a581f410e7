//! The rotary-table measurement job (`gateway rotary measure --config`): the simulated
//! 5-axis machine it runs on, and the adapter that lets the measurement cycle drive it.
//!
//! The machine is the emulated one (world::rotary) in-process, the same behind the GRBL
//! emulator on a pseudo-terminal (`"link": "grbl_emulator"`), or a real controller on a
//! serial port (`"link": {"grbl": {"port": "/dev/ttyUSB0"}}`), whose truth nobody knows.

use rotary::measure::{MeasurePlan, ProbingMachine};
use rotary::{Axes, MachineConstants};
use serde::{Deserialize, Serialize};
use world::rotary::{Geometry, RotaryMachineSim, TableErrors, TouchProbe};

/// The job file (JSON): every part optional, defaults are the paper's table.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RotaryJob {
    /// The simulated machine's seed (probe noise).
    #[serde(default)]
    pub seed: u64,
    /// The simulated table's true location errors (default: the paper's).
    pub errors: Option<TableErrors>,
    /// The simulated probe (default: 1.5 mm stylus, 0.8 um pre-travel, 0.3 um noise).
    pub probe: Option<TouchProbe>,
    /// The cycle's settings (default: [`MeasurePlan::default`]).
    pub plan: Option<MeasurePlan>,
    /// The nominal machine constants the gateway knows (default: the built-in ones).
    pub machine: Option<MachineConstants>,
    /// Machine speeds for the simulated time.
    pub speeds: Option<Speeds>,
    /// Run the cycle through a controller link instead of in-process (`"grbl_emulator"`:
    /// the GRBL emulator with this job's machine behind it, on a pseudo-terminal,
    /// driven by the GRBL driver; `{"grbl": {"port": ..}}`: a real controller).
    pub link: Option<RotaryLink>,
}

/// The controller link a measurement job runs through.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RotaryLink {
    GrblEmulator,
    /// A GRBL-family controller (grblHAL with A and C axes and a probe input) on a
    /// serial port; the simulated parts of the job (seed, errors, probe, speeds) are
    /// refused beside it, since they would describe a machine that is not there.
    Grbl(GrblPort),
}

/// A controller's serial port.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GrblPort {
    /// The device path (`/dev/ttyUSB0`, `/dev/ttyACM0`, a pseudo-terminal).
    pub port: String,
    /// Baud rate (GRBL's 115200 unless the controller was built otherwise).
    #[serde(default = "default_baud")]
    pub baud: u32,
    /// Status polling period while waiting for motion, ms (the driver's 20 by default).
    pub poll_ms: Option<u64>,
}

fn default_baud() -> u32 {
    115_200
}

/// The simulated table's true errors under the paper's names (what an identification
/// is compared with).
pub fn injected_errors(t: &TableErrors) -> rotary::LocationErrors {
    rotary::LocationErrors {
        delta_xc_mm: t.delta_xc_mm,
        delta_yc_mm: t.delta_yc_mm,
        alpha_xc_deg: t.alpha_xc_deg,
        alpha_yc_deg: t.alpha_yc_deg,
        delta_ya_mm: t.delta_ya_mm,
        delta_za_mm: t.delta_za_mm,
        alpha_ya_deg: t.alpha_ya_deg,
        alpha_za_deg: t.alpha_za_deg,
    }
}

/// How fast the simulated machine moves.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Speeds {
    pub rapid_mm_min: f64,
    pub rotary_deg_min: f64,
}

impl Default for Speeds {
    fn default() -> Self {
        Self {
            rapid_mm_min: 3000.0,
            rotary_deg_min: 3600.0,
        }
    }
}

impl RotaryJob {
    /// Reads the job from JSON text; errors name the field.
    pub fn from_json(text: &str) -> Result<Self, String> {
        let job: RotaryJob = serde_json::from_str(text).map_err(|e| e.to_string())?;
        if let Some(m) = &job.machine {
            m.check()?;
        }
        job.check_numbers()?;
        if let Some(RotaryLink::Grbl(port)) = &job.link {
            let simulated = [
                ("seed", job.seed != 0),
                ("errors", job.errors.is_some()),
                ("probe", job.probe.is_some()),
                ("speeds", job.speeds.is_some()),
            ];
            if let Some((name, _)) = simulated.iter().find(|(_, set)| *set) {
                return Err(format!(
                    "`{name}` describes the simulated machine; the job's link is the real \
                     controller on {}",
                    port.port
                ));
            }
            if port.port.trim().is_empty() {
                return Err("link.grbl.port: empty device path".into());
            }
            if port.poll_ms == Some(0) {
                return Err("link.grbl.poll_ms: must be at least 1".into());
            }
        }
        Ok(job)
    }

    /// Every number of the job within a range that makes physical sense, refused naming
    /// its field and the range (issue 38: a speed of 4e-320 made every move take
    /// forever, a poll period of 10^18 ms never polled, errors of 1e300 mm were
    /// simulated). Where zero means something (an error, a noise) it is allowed.
    fn check_numbers(&self) -> Result<(), String> {
        let mut numbers: Vec<(String, f64, f64, f64, &str)> = Vec::new();
        let mut add = |key: &str, v: f64, lo: f64, hi: f64, unit: &'static str| {
            numbers.push((key.to_string(), v, lo, hi, unit));
        };
        if let Some(e) = &self.errors {
            for (k, v) in [
                ("delta_xc_mm", e.delta_xc_mm),
                ("delta_yc_mm", e.delta_yc_mm),
                ("delta_ya_mm", e.delta_ya_mm),
                ("delta_za_mm", e.delta_za_mm),
            ] {
                add(&format!("errors.{k}"), v, -10.0, 10.0, "mm");
            }
            for (k, v) in [
                ("alpha_xc_deg", e.alpha_xc_deg),
                ("alpha_yc_deg", e.alpha_yc_deg),
                ("alpha_ya_deg", e.alpha_ya_deg),
                ("alpha_za_deg", e.alpha_za_deg),
            ] {
                add(&format!("errors.{k}"), v, -1.0, 1.0, "deg");
            }
        }
        if let Some(p) = &self.probe {
            add(
                "probe.stylus_radius_mm",
                p.stylus_radius_mm,
                0.1,
                25.0,
                "mm",
            );
            add("probe.pre_travel_mm", p.pre_travel_mm, 0.0, 1.0, "mm");
            add("probe.noise_mm", p.noise_mm, 0.0, 0.1, "mm");
        }
        if let Some(s) = &self.speeds {
            add(
                "speeds.rapid_mm_min",
                s.rapid_mm_min,
                1.0,
                100_000.0,
                "mm/min",
            );
            add(
                "speeds.rotary_deg_min",
                s.rotary_deg_min,
                1.0,
                100_000.0,
                "deg/min",
            );
        }
        if let Some(p) = &self.plan {
            for (k, b) in p.artifact.balls.iter().enumerate() {
                add(
                    &format!("plan.artifact.balls[{k}].radius_mm"),
                    b.radius_mm,
                    0.5,
                    500.0,
                    "mm",
                );
                for (c, v) in b.centre_mm.iter().enumerate() {
                    add(
                        &format!("plan.artifact.balls[{k}].centre_mm[{c}]"),
                        *v,
                        -10_000.0,
                        10_000.0,
                        "mm",
                    );
                }
            }
            add("plan.stylus_radius_mm", p.stylus_radius_mm, 0.1, 25.0, "mm");
            add("plan.approach_mm", p.approach_mm, 0.01, 100.0, "mm");
            add("plan.overtravel_mm", p.overtravel_mm, 0.01, 100.0, "mm");
            add("plan.backoff_mm", p.backoff_mm, 0.01, 100.0, "mm");
            add(
                "plan.fast_feed_mm_min",
                p.fast_feed_mm_min,
                1.0,
                100_000.0,
                "mm/min",
            );
            add(
                "plan.slow_feed_mm_min",
                p.slow_feed_mm_min,
                1.0,
                100_000.0,
                "mm/min",
            );
            add("plan.cone_deg", p.cone_deg, 1.0, 179.0, "deg");
            add(
                "plan.radius_tolerance_mm",
                p.radius_tolerance_mm,
                1e-4,
                10.0,
                "mm",
            );
            add(
                "plan.residual_limit_mm",
                p.residual_limit_mm,
                1e-5,
                10.0,
                "mm",
            );
            add("plan.safe_z_mm", p.safe_z_mm, -10_000.0, 10_000.0, "mm");
            let r = &p.rim;
            add("plan.rim.radius_mm", r.radius_mm, 1.0, 5000.0, "mm");
            add("plan.rim.depth_mm", r.depth_mm, 0.01, 1000.0, "mm");
            for (k, v) in r.angles_deg.iter().enumerate() {
                add(
                    &format!("plan.rim.angles_deg[{k}]"),
                    *v,
                    -360.0,
                    360.0,
                    "deg",
                );
            }
            add(
                "plan.rim.radius_tolerance_mm",
                r.radius_tolerance_mm,
                1e-4,
                100.0,
                "mm",
            );
            add(
                "plan.rim.max_offset_mm",
                r.max_offset_mm,
                1e-3,
                1000.0,
                "mm",
            );
            if let Some(d) = r.protected_descent_mm {
                add("plan.rim.protected_descent_mm", d, 0.01, 1000.0, "mm");
            }
        }
        if let Some(RotaryLink::Grbl(port)) = &self.link {
            add(
                "link.grbl.baud",
                f64::from(port.baud),
                f64::from(crate::bounds::MIN_BAUD),
                f64::from(crate::bounds::MAX_BAUD),
                "baud",
            );
            if let Some(ms) = port.poll_ms {
                add("link.grbl.poll_ms", ms as f64, 1.0, 10_000.0, "ms");
            }
        }
        for (key, v, lo, hi, unit) in numbers {
            if !(v.is_finite() && v >= lo && v <= hi) {
                return Err(format!("{key}: {v:e} {unit} is outside {lo}..={hi} {unit}"));
            }
        }
        Ok(())
    }

    /// The simulated machine this job describes.
    pub fn simulated(&self) -> SimulatedTable {
        let constants = self.machine.unwrap_or_default();
        let geometry = Geometry {
            a_axis_y_mm: constants.a_axis_y_mm,
            a_axis_z_mm: constants.a_axis_z_mm,
            ac_offset_y_mm: constants.ac_offset_y_mm,
            ac_offset_z_mm: constants.ac_offset_z_mm,
            tool_length_mm: constants.tool_length_mm,
        };
        let sim = RotaryMachineSim::new(
            geometry,
            self.errors.unwrap_or_default(),
            self.probe.unwrap_or_default(),
            self.seed,
        );
        SimulatedTable::new(sim, self.speeds.unwrap_or_default())
    }
}

/// The simulated machine as the measurement cycle sees it, with a clock of simulated
/// machine time (moves at their speeds, linear and rotary together).
pub struct SimulatedTable {
    pub sim: RotaryMachineSim,
    pub speeds: Speeds,
    position: [f64; 5],
    /// Simulated machine time so far, seconds.
    pub time_s: f64,
    pub moves: usize,
}

impl SimulatedTable {
    pub fn new(sim: RotaryMachineSim, speeds: Speeds) -> Self {
        Self {
            sim,
            speeds,
            position: [0.0, 0.0, 0.0, 0.0, 0.0],
            time_s: 0.0,
            moves: 0,
        }
    }

    pub fn position(&self) -> [f64; 5] {
        self.position
    }
}

fn distance(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).powi(2))
        .sum::<f64>()
        .sqrt()
}

impl ProbingMachine for SimulatedTable {
    fn move_to(&mut self, t: &Axes) -> Result<(), String> {
        let target = [t.x, t.y, t.z, t.a, t.c];
        if target.iter().any(|v| !v.is_finite()) {
            return Err(format!("move to {target:?}: not a position"));
        }
        let linear = distance(&self.position[..3], &target[..3]) / self.speeds.rapid_mm_min;
        let rotary = (self.position[3] - target[3])
            .abs()
            .max((self.position[4] - target[4]).abs())
            / self.speeds.rotary_deg_min;
        self.time_s += linear.max(rotary) * 60.0;
        self.position = target;
        self.moves += 1;
        Ok(())
    }

    fn probe_towards(
        &mut self,
        to: [f64; 3],
        feed_mm_min: f64,
    ) -> Result<Option<[f64; 3]>, String> {
        if !(feed_mm_min > 0.0) {
            return Err(format!("probing feed {feed_mm_min} mm/min"));
        }
        let from = [self.position[0], self.position[1], self.position[2]];
        let hit = self
            .sim
            .probe_move(from, to, self.position[3], self.position[4]);
        let stop = hit.unwrap_or(to);
        self.time_s += distance(&from, &stop) / feed_mm_min * 60.0;
        self.position[..3].copy_from_slice(&stop);
        self.moves += 1;
        Ok(hit)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rotary::measure::{measure, Action, MeasureError, MeasureSession};

    /// Issue 38: every number of the rotary job file is bounded and named; the
    /// defaults and the paper's plan, written out whole, read back.
    #[test]
    fn every_number_of_the_rotary_job_is_bounded_and_named() {
        let whole = |plan: MeasurePlan| {
            let job = RotaryJob {
                seed: 3,
                errors: Some(TableErrors::default()),
                probe: Some(TouchProbe::default()),
                plan: Some(plan),
                machine: Some(MachineConstants::default()),
                speeds: Some(Speeds::default()),
                link: None,
            };
            serde_json::to_value(job).unwrap()
        };
        for plan in [MeasurePlan::default(), MeasurePlan::paper()] {
            let text = whole(plan).to_string();
            RotaryJob::from_json(&text).unwrap_or_else(|e| panic!("{e}: {text}"));
        }
        let base = whole(MeasurePlan::default());
        let cases: &[(&[&str], &str)] = &[
            (&["speeds", "rapid_mm_min"], "speeds.rapid_mm_min"),
            (&["speeds", "rotary_deg_min"], "speeds.rotary_deg_min"),
            (&["errors", "delta_xc_mm"], "errors.delta_xc_mm"),
            (&["errors", "alpha_za_deg"], "errors.alpha_za_deg"),
            (&["probe", "stylus_radius_mm"], "probe.stylus_radius_mm"),
            (&["probe", "noise_mm"], "probe.noise_mm"),
            (&["plan", "approach_mm"], "plan.approach_mm"),
            (&["plan", "slow_feed_mm_min"], "plan.slow_feed_mm_min"),
            (&["plan", "cone_deg"], "plan.cone_deg"),
            (&["plan", "residual_limit_mm"], "plan.residual_limit_mm"),
            (&["plan", "safe_z_mm"], "plan.safe_z_mm"),
            (&["plan", "rim", "radius_mm"], "plan.rim.radius_mm"),
            (&["plan", "rim", "max_offset_mm"], "plan.rim.max_offset_mm"),
        ];
        // Errors and noise may be zero, so only their magnitudes are absurd; the others
        // also refuse a subnormal, zero and a negative value.
        for (path, key) in cases {
            let zero_ok =
                key.starts_with("errors.") || *key == "probe.noise_mm" || *key == "plan.safe_z_mm";
            let signed = key.starts_with("errors.") || *key == "plan.safe_z_mm";
            let mut bad = vec![1e308, -1e308, 1e100];
            if !zero_ok {
                bad.extend([4e-320, 0.0]);
            }
            if !signed {
                bad.push(-1.0);
            }
            for v in bad {
                let mut job = base.clone();
                let mut at = &mut job;
                for p in *path {
                    at = at.get_mut(*p).unwrap();
                }
                *at = serde_json::json!(v);
                let e = RotaryJob::from_json(&job.to_string())
                    .map(|_| panic!("{key} = {v:e} accepted"))
                    .unwrap_err();
                assert!(
                    e.starts_with(&format!("{key}: ")) && e.contains("..="),
                    "{key} = {v:e}: {e}"
                );
            }
        }
        let link =
            r#"{"link": {"grbl": {"port": "/dev/ttyUSB0", "poll_ms": 1000000000000000000}}}"#;
        let e = RotaryJob::from_json(link).unwrap_err();
        assert!(e.starts_with("link.grbl.poll_ms"), "{e}");
        let link = r#"{"link": {"grbl": {"port": "/dev/ttyUSB0", "baud": 0}}}"#;
        let e = RotaryJob::from_json(link).unwrap_err();
        assert!(e.starts_with("link.grbl.baud"), "{e}");
    }

    /// The simulated table, failing call number `at` (1-based).
    struct FailAt {
        table: SimulatedTable,
        calls: usize,
        at: usize,
    }

    impl ProbingMachine for FailAt {
        fn move_to(&mut self, t: &Axes) -> Result<(), String> {
            self.calls += 1;
            if self.calls == self.at {
                return Err("link lost".into());
            }
            self.table.move_to(t)
        }

        fn probe_towards(&mut self, to: [f64; 3], feed: f64) -> Result<Option<[f64; 3]>, String> {
            self.calls += 1;
            if self.calls == self.at {
                return Err("link lost".into());
            }
            self.table.probe_towards(to, feed)
        }
    }

    /// The cycle, driven by its session, on the simulated table: the figures the
    /// synchronous cycle always gave (every call of it counted: 1637 moves and probing
    /// moves, 462 touches, 38 balls).
    #[test]
    fn the_cycle_on_the_simulated_table_keeps_its_figures() {
        let mut table = RotaryJob::default().simulated();
        let m = measure(
            &mut table,
            &MachineConstants::default(),
            &MeasurePlan::paper(),
            |_, _| {},
        )
        .unwrap_or_else(|s| panic!("{}", s.error));
        assert_eq!(table.moves, 1637);
        assert_eq!(m.probe_touches, 462);
        assert_eq!(m.balls.len(), 38);
        assert!(m.c_centre.is_some());
    }

    /// A machine failing at call `at` stops the cycle with what the synchronous cycle
    /// kept there: (call, balls, touches, C centre located).
    #[test]
    fn a_failure_keeps_what_the_cycle_always_kept() {
        for (at, balls, touches, located) in [
            (1, 0, 0, false),
            (4, 0, 1, false),
            (10, 0, 2, false),
            (37, 0, 10, true),
            (204, 4, 57, true),
            (207, 4, 58, true),
            (400, 8, 112, true),
        ] {
            let mut machine = FailAt {
                table: RotaryJob::default().simulated(),
                calls: 0,
                at,
            };
            let stopped = measure(
                &mut machine,
                &MachineConstants::default(),
                &MeasurePlan::paper(),
                |_, _| {},
            )
            .expect_err("the machine failed");
            assert_eq!(stopped.error, MeasureError::Machine("link lost".into()));
            let m = &stopped.so_far;
            assert_eq!(
                (m.balls.len(), m.probe_touches, m.c_centre.is_some()),
                (balls, touches, located),
                "failure at call {at}"
            );
        }
    }

    /// A stop after n balls keeps the n balls (and the rim), on the simulated table.
    #[test]
    fn a_stop_after_n_balls_keeps_them() {
        for n in [1, 2, 20] {
            let mut table = RotaryJob::default().simulated();
            let mut s = MeasureSession::new(&MachineConstants::default(), &MeasurePlan::paper());
            loop {
                if s.progress().0 == n {
                    s.stop();
                }
                match s.next_action() {
                    Action::Finished => break,
                    Action::MoveTo(t) => {
                        table.move_to(&t).unwrap();
                        s.moved();
                    }
                    Action::ProbeTowards { to, feed_mm_min } => {
                        s.probed(table.probe_towards(to, feed_mm_min).unwrap())
                    }
                }
            }
            let stopped = s.finish().expect_err("stopped");
            assert_eq!(stopped.error, MeasureError::StopRequested);
            assert_eq!(stopped.so_far.balls.len(), n);
            // The rim's 3 points and 6 per ball, each touched fast then slow.
            assert_eq!(stopped.so_far.probe_touches, (3 + 6 * n) * 2);
        }
    }
}
