//! Opening a `modbus` stage: the drives on their TCP address or RTU port, or the drive
//! emulator on a loopback port or a pseudo-terminal driving a new simulated machine.

use crate::emulated::{new_rig, EmulatedStage, OpenedStage};
use crate::error::OpenError;
use drivers::modbus::{Endpoint, ModbusOptions, Parity};
use drivers::{Axis, StageLink};
use emulators::modbus::{DriveSet, MachineAxis, ModbusDevice, ModbusRtu, ModbusTcp};
use job::modbus::{ModbusLink, ModbusStageSpec};
use job::Job;
use std::time::Duration;
use world::Clock;

fn link(spec: &ModbusStageSpec, endpoint: Endpoint, options: ModbusOptions) -> StageLink {
    StageLink::Modbus {
        endpoint,
        options,
        profile: spec.profile.clone(),
        axes: spec.axes.clone(),
    }
}

/// Open a job's `modbus` stage: the drives on their TCP address or RTU port, or the
/// drive emulator on a loopback port or a pseudo-terminal driving a new simulated
/// machine (returned as the rig). Must run inside the tokio runtime that will run the
/// job (the emulator serves from tasks of that runtime).
pub(crate) async fn open(job: &Job, spec: &ModbusStageSpec) -> Result<OpenedStage, OpenError> {
    let real = |endpoint| link(spec, endpoint, spec.options());
    match &spec.link {
        ModbusLink::Tcp(addr) => Ok((
            drivers::open_stage(&real(Endpoint::Tcp(*addr))).await?,
            None,
        )),
        ModbusLink::Rtu { port, baud, parity } => {
            let endpoint = Endpoint::Rtu {
                path: port.clone(),
                baud: *baud,
                parity: *parity,
            };
            Ok((drivers::open_stage(&real(endpoint)).await?, None))
        }
        ModbusLink::Emulate { machine, rtu } => {
            let rig = new_rig(job, machine);
            let units: Vec<(u8, MachineAxis)> = spec
                .axes
                .iter()
                .map(|a| {
                    (
                        a.unit,
                        if a.axis == Axis::X {
                            MachineAxis::X
                        } else {
                            MachineAxis::Y
                        },
                    )
                })
                .collect();
            // Motion completes as soon as the driver has seen it start.
            let set = DriveSet::new(
                rig.clone(),
                spec.profile.clone(),
                &units,
                Clock::Unconstrained,
            );
            let device = ModbusDevice::new(set);
            let emulator_error = |e: std::io::Error| OpenError::Emulator {
                what: "Modbus drive emulator",
                message: e.to_string(),
            };
            let options = ModbusOptions {
                poll_interval: Duration::from_millis(1),
                ..spec.options()
            };
            let stage = if *rtu {
                let line = ModbusRtu::spawn(device, None).map_err(emulator_error)?;
                let endpoint = Endpoint::Rtu {
                    path: line.path().to_string(),
                    baud: 115_200,
                    parity: Parity::None,
                };
                let stage = drivers::open_stage(&link(spec, endpoint, options)).await?;
                EmulatedStage::new(stage, line)
            } else {
                let server = ModbusTcp::bind(device, ([127, 0, 0, 1], 0).into())
                    .await
                    .map_err(emulator_error)?;
                let endpoint = Endpoint::Tcp(server.local_addr());
                let stage = drivers::open_stage(&link(spec, endpoint, options)).await?;
                EmulatedStage::new(stage, server)
            };
            Ok((Box::new(stage), Some(rig)))
        }
    }
}
