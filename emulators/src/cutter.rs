//! The conveyor cutter of source C on pseudo-terminals: one GRBL controller for the
//! conveyor (its X axis feeds the material) and one per knife head (X, Y over its part of
//! the cutting area, Z the knife), as a retrofit with one cheap controller per gantry
//! would have them. All share one [`world::cutter::CutLog`] of every knife stroke.

use crate::grbl::{GrblConfig, GrblDevice, GrblPty};
use std::io;
use world::axes::{lock_axes, AxesMachine, SharedAxes};
use world::cutter::{lock_log, Conveyor, CutLog, CutterGeometry, Head, SharedCutLog};

/// The running cutter: its controllers' ports and its log.
pub struct CutterPty {
    pub conveyor: GrblPty,
    pub heads: Vec<GrblPty>,
    log: SharedCutLog,
    conveyor_axes: SharedAxes,
    head_axes: Vec<SharedAxes>,
}

impl CutterPty {
    /// Start the k + 1 controllers (GRBL 1.1 on pseudo-terminals, motion on the
    /// unconstrained clock). Must be called inside a tokio runtime.
    pub fn spawn(geometry: &CutterGeometry) -> io::Result<CutterPty> {
        let log = SharedCutLog::default();
        let conveyor_axes =
            AxesMachine::new(Box::new(Conveyor::new(geometry, log.clone()))).shared();
        let conveyor = GrblPty::spawn(
            GrblDevice::with_axes(conveyor_axes.clone(), GrblConfig::default()),
            None,
        )?;
        let mut heads = Vec::new();
        let mut head_axes = Vec::new();
        for index in 0..geometry.heads.len() {
            let axes = AxesMachine::new(Box::new(Head::new(
                index,
                geometry,
                conveyor_axes.clone(),
                log.clone(),
            )))
            .shared();
            heads.push(GrblPty::spawn(
                GrblDevice::with_axes(axes.clone(), GrblConfig::default()),
                None,
            )?);
            head_axes.push(axes);
        }
        Ok(CutterPty {
            conveyor,
            heads,
            log,
            conveyor_axes,
            head_axes,
        })
    }

    /// The head controllers' ports, head 0 first.
    pub fn head_paths(&self) -> Vec<String> {
        self.heads.iter().map(|h| h.path().to_string()).collect()
    }

    /// Everything cut so far.
    pub fn log(&self) -> CutLog {
        lock_log(&self.log).clone()
    }

    /// The simulated seconds each machine has run: the conveyor's, then each head's.
    pub fn clocks_s(&self) -> (f64, Vec<f64>) {
        (
            lock_axes(&self.conveyor_axes).now_s(),
            self.head_axes
                .iter()
                .map(|a| lock_axes(a).now_s())
                .collect(),
        )
    }
}
