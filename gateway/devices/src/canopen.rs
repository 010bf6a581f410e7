//! Opening a `canopen` stage: the nodes on a real bus, or the CiA 402 drive emulator
//! behind an SLCAN adapter on a pseudo-terminal driving a new simulated machine.

use crate::emulated::{new_rig, EmulatedStage, OpenedStage};
use crate::error::OpenError;
use drivers::can::BusSpec;
use drivers::{Axis, StageLink};
use emulators::canopen::{DriveSet, DriveSetConfig, SlcanPty, DRIVE_EDS, DRIVE_EDS_NAME};
use job::canopen::{CanopenLink, CanopenStageSpec};
use job::Job;
use std::sync::{Arc, Mutex};
use world::Clock;

fn link(spec: &CanopenStageSpec, bus: BusSpec) -> StageLink {
    StageLink::Canopen {
        bus,
        options: spec.options.clone(),
        axes: spec.axes.clone(),
    }
}

/// Open a job's `canopen` stage: the nodes on a real bus, or the drive emulator on an
/// SLCAN pseudo-terminal driving a new simulated machine (returned as the rig). Must
/// run inside the tokio runtime that will run the job (the bus task and the emulator
/// are tasks of that runtime).
pub(crate) async fn open(job: &Job, spec: &CanopenStageSpec) -> Result<OpenedStage, OpenError> {
    match &spec.link {
        CanopenLink::Bus(bus) => Ok((drivers::open_stage(&link(spec, bus.clone())).await?, None)),
        CanopenLink::Emulate { machine, eds } => {
            let rig = new_rig(job, machine);
            let nodes = spec
                .axes
                .iter()
                .map(|a| (a.node, if a.axis == Axis::X { 0 } else { 1 }))
                .collect();
            // Motion completes as soon as the driver has seen it start.
            let cfg = DriveSetConfig {
                clock: Clock::Unconstrained,
                nodes,
                eds: eds
                    .clone()
                    .unwrap_or_else(|| (DRIVE_EDS_NAME.to_string(), DRIVE_EDS.to_string())),
            };
            let emulator_error = |message: String| OpenError::Emulator {
                what: "CiA 402 drive emulator",
                message,
            };
            let set =
                DriveSet::new(rig.clone(), &cfg, 0.0).map_err(|e| emulator_error(e.to_string()))?;
            let emulator = SlcanPty::spawn(Arc::new(Mutex::new(set)), None)
                .map_err(|e| emulator_error(format!("cannot create a pseudo-terminal: {e}")))?;
            let bus = BusSpec::Slcan {
                port: emulator.path().to_string(),
                bitrate: 1_000_000,
            };
            let stage = drivers::open_stage(&link(spec, bus)).await?;
            Ok((Box::new(EmulatedStage::new(stage, emulator)), Some(rig)))
        }
    }
}
