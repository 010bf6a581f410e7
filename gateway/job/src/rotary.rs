//! The rotary-table measurement job (`gateway rotary measure --config`): the simulated
//! 5-axis machine it runs on, and the adapter that lets the measurement cycle drive it.
//!
//! The machine is the emulated one (world::rotary): the probing link through a real
//! controller is not part of this job yet.

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
    /// driven by the GRBL driver).
    pub link: Option<RotaryLink>,
}

/// The controller link a measurement job runs through.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RotaryLink {
    GrblEmulator,
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
