//! Opening a `modbus` stage: the drives on their TCP address or RTU port, or the drive
//! emulator on a loopback port or a pseudo-terminal driving a new simulated machine.

use crate::{new_rig, EmulatedStage, OpenedStage};
use drivers::modbus::{open_stage, Endpoint, Parity};
use drivers::{Axis, DriverError};
use emulators::modbus::{DriveSet, MachineAxis, ModbusDevice, ModbusRtu, ModbusTcp};
use job::modbus::{ModbusLink, ModbusStageSpec};
use job::Job;
use std::time::Duration;
use world::Clock;

/// Open a job's `modbus` stage: the drives on their TCP address or RTU port, or the
/// drive emulator on a loopback port or a pseudo-terminal driving a new simulated
/// machine (returned as the rig). Must run inside the tokio runtime that will run the
/// job (the emulator serves from tasks of that runtime).
pub(crate) async fn open(job: &Job, spec: &ModbusStageSpec) -> Result<OpenedStage, DriverError> {
    let mut opts = spec.options();
    let real = |endpoint| open_stage(endpoint, spec.options(), spec.profile.clone(), &spec.axes);
    match &spec.link {
        ModbusLink::Tcp(addr) => Ok((Box::new(real(Endpoint::Tcp(*addr)).await?), None)),
        ModbusLink::Rtu { port, baud, parity } => {
            let endpoint = Endpoint::Rtu {
                path: port.clone(),
                baud: *baud,
                parity: *parity,
            };
            Ok((Box::new(real(endpoint).await?), None))
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
            let emulator_error = |e: std::io::Error| DriverError::Transport {
                device: "Modbus drive emulator".into(),
                message: e.to_string(),
            };
            opts.poll_interval = Duration::from_millis(1);
            let stage = if *rtu {
                let line = ModbusRtu::spawn(device, None).map_err(emulator_error)?;
                let ep = Endpoint::Rtu {
                    path: line.path().to_string(),
                    baud: 115_200,
                    parity: Parity::None,
                };
                let stage = open_stage(ep, opts, spec.profile.clone(), &spec.axes).await?;
                EmulatedStage::new(stage, line)
            } else {
                let server = ModbusTcp::bind(device, ([127, 0, 0, 1], 0).into())
                    .await
                    .map_err(emulator_error)?;
                let ep = Endpoint::Tcp(server.local_addr());
                let stage = open_stage(ep, opts, spec.profile.clone(), &spec.axes).await?;
                EmulatedStage::new(stage, server)
            };
            Ok((Box::new(stage), Some(rig)))
        }
    }
}
