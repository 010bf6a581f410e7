//! Opening a `canopen` stage: the nodes on a real bus, or the CiA 402 drive emulator
//! behind an SLCAN adapter on a pseudo-terminal driving a new simulated machine.

use crate::{new_rig, EmulatedStage, OpenedStage};
use drivers::can::{open_bus, BusSpec};
use drivers::canopen::open_stage;
use drivers::{Axis, DriverError};
use emulators::canopen::{DriveSet, DriveSetConfig, SlcanPty, DRIVE_EDS, DRIVE_EDS_NAME};
use job::canopen::{CanopenLink, CanopenStageSpec};
use job::Job;
use std::sync::{Arc, Mutex};
use world::Clock;

/// Open a job's `canopen` stage: the nodes on a real bus, or the drive emulator on an
/// SLCAN pseudo-terminal driving a new simulated machine (returned as the rig). Must
/// run inside the tokio runtime that will run the job (the bus task and the emulator
/// are tasks of that runtime).
pub(crate) async fn open(job: &Job, spec: &CanopenStageSpec) -> Result<OpenedStage, DriverError> {
    match &spec.link {
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
            let set =
                DriveSet::new(rig.clone(), &cfg, 0.0).map_err(|e| DriverError::Unsupported {
                    device: "CiA 402 drive emulator".into(),
                    message: e.to_string(),
                })?;
            let emulator = SlcanPty::spawn(Arc::new(Mutex::new(set)), None).map_err(|e| {
                DriverError::Transport {
                    device: "CiA 402 drive emulator".into(),
                    message: format!("cannot create a pseudo-terminal: {e}"),
                }
            })?;
            let bus = open_bus(&BusSpec::Slcan {
                port: emulator.path().to_string(),
                bitrate: 1_000_000,
            })
            .await?;
            let (stage, _net) = open_stage(bus, spec.axes.clone(), spec.options.clone()).await?;
            Ok((Box::new(EmulatedStage::new(stage, emulator)), Some(rig)))
        }
        CanopenLink::Bus(bus) => {
            let bus = open_bus(bus).await?;
            let (stage, _net) = open_stage(bus, spec.axes.clone(), spec.options.clone()).await?;
            Ok((Box::new(stage), None))
        }
    }
}
