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
