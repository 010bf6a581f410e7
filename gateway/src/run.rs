//! Opening the devices a job names, and running the job to a report.

use crate::config::{CameraSpec, Job, StageSpec};
use crate::orchestrator::{Event, Orchestrator};
use crate::report::{Report, TruthAt};
use drivers::sim::{SharedRig, SimCamera, SimStage};
use drivers::{Camera, DriverError, Stage};
use emulators::machine::SimMachine;
use emulators::rig::SimRig;
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// The devices of a job. `rig` is set when the machine is simulated: it is how reports
/// learn the truth; the pipeline never receives it.
pub struct Devices {
    pub stage: Box<dyn Stage>,
    pub camera: Box<dyn Camera>,
    pub rig: Option<SharedRig>,
}

pub fn open_devices(job: &Job) -> Result<Devices, DriverError> {
    if job.camera_link != crate::camera_link::CameraLink::Direct {
        return Err(DriverError::NotAvailable {
            backend: "camera link".into(),
            reason: "a GigE Vision or replay camera is opened inside the async runtime: use run::open_devices_async".into(),
        });
    }
    open_sim(job)
}

fn open_sim(job: &Job) -> Result<Devices, DriverError> {
    match (&job.stage, &job.camera) {
        (StageSpec::Sim { machine }, CameraSpec::Sim { model }) => {
            let rig = SimRig::new(
                SimMachine::new(machine.clone()),
                job.board.clone(),
                model.clone(),
            );
            let rig: SharedRig = Arc::new(Mutex::new(rig));
            Ok(Devices {
                stage: Box::new(SimStage::new(rig.clone())),
                camera: Box::new(SimCamera::new(rig.clone())),
                rig: Some(rig),
            })
        }
        (StageSpec::Grbl { .. }, _) => Err(DriverError::NotAvailable {
            backend: "grbl".into(),
            reason: "a GRBL stage is opened inside the async runtime: use run::open_devices_async"
                .into(),
        }),
        (StageSpec::Canopen(_), _) => Err(DriverError::NotAvailable {
            backend: "canopen".into(),
            reason:
                "a CANopen stage is opened inside the async runtime: use run::open_devices_async"
                    .into(),
        }),
        (StageSpec::Modbus(_), _) => Err(DriverError::NotAvailable {
            backend: "modbus".into(),
            reason:
                "a Modbus stage is opened inside the async runtime: use run::open_devices_async"
                    .into(),
        }),
    }
}

/// Open the devices of any job, including those that need the async runtime to
/// connect (GRBL). Call from inside the runtime that will run the job.
pub async fn open_devices_async(job: &Job) -> Result<Devices, DriverError> {
    // A real GRBL controller with a real camera (or an emulator process serving both
    // on one simulated machine, `emulators gige --stage grbl`): no in-process rig.
    if let (
        StageSpec::Grbl {
            port: Some(port),
            baud,
            emulate: None,
        },
        true,
    ) = (&job.stage, job.camera_link.is_external())
    {
        let camera = crate::camera_link::open_external(&job.camera_link).await?;
        let stage = drivers::grbl::GrblStage::open(port, *baud, Default::default()).await?;
        return Ok(Devices {
            stage: Box::new(stage),
            camera,
            rig: None,
        });
    }
    // Real Modbus drives (TCP or RTU) with a real camera, likewise.
    if let (StageSpec::Modbus(spec), true) = (&job.stage, job.camera_link.is_external()) {
        use crate::modbus_stage::ModbusLink;
        use drivers::modbus::{open_stage, Endpoint, ModbusOptions};
        let endpoint = match &spec.link {
            ModbusLink::Tcp(a) => Some(Endpoint::Tcp(*a)),
            ModbusLink::Rtu { port, baud, parity } => Some(Endpoint::Rtu {
                path: port.clone(),
                baud: *baud,
                parity: *parity,
            }),
            ModbusLink::Emulate { .. } => None,
        };
        if let Some(endpoint) = endpoint {
            let camera = crate::camera_link::open_external(&job.camera_link).await?;
            let opts = ModbusOptions {
                timeout: std::time::Duration::from_millis(spec.timeout_ms),
                retries: spec.retries,
                ..Default::default()
            };
            let stage = open_stage(endpoint, opts, spec.profile.clone(), &spec.axes).await?;
            return Ok(Devices {
                stage: Box::new(stage),
                camera,
                rig: None,
            });
        }
    }
    // Real CiA 402 drives on a CAN bus (SLCAN or SocketCAN) with a real camera, likewise.
    if let (StageSpec::Canopen(spec), true) = (&job.stage, job.camera_link.is_external()) {
        if let crate::canopen_stage::CanopenLink::Bus(bus) = &spec.link {
            let camera = crate::camera_link::open_external(&job.camera_link).await?;
            let bus = drivers::can::open_bus(bus).await?;
            let (stage, _network) =
                drivers::canopen::open_stage(bus, spec.axes.clone(), spec.options.clone()).await?;
            return Ok(Devices {
                stage: Box::new(stage),
                camera,
                rig: None,
            });
        }
    }
    let mut devices = match &job.stage {
        StageSpec::Grbl { .. } => crate::grbl_stage::open(job).await,
        StageSpec::Modbus(_) => crate::modbus_stage::open(job).await,
        StageSpec::Canopen(_) => crate::canopen_stage::open(job).await,
        StageSpec::Sim { .. } => open_sim(job),
    }?;
    // GigE Vision or replayed frames instead of the in-process camera.
    crate::camera_link::attach(&job.camera_link, &mut devices).await?;
    Ok(devices)
}

/// Progress callback: (targets done, targets planned).
pub type Progress<'a> = &'a mut dyn FnMut(usize, usize);

/// Run a job on opened devices and build its report (also when it stopped early).
pub async fn run_job(job: &Job, devices: &mut Devices, progress: Progress<'_>) -> Report {
    let started = Instant::now();
    let rig = devices.rig.clone();
    // Truth error (um) at the first and latest measurement of each target.
    let mut truth: Vec<Option<TruthAt>> = Vec::new();
    let mut current: Option<(usize, TruthAt)> = None;
    let mut on_event = |e: Event| match e {
        Event::Measured { target_index, .. } => {
            if let Some(rig) = &rig {
                let pose = rig.lock().unwrap_or_else(|p| p.into_inner()).truth();
                let t = job.targets[target_index];
                let err = [
                    (pose.centre_mm[0] - t[0]) * 1000.0,
                    (pose.centre_mm[1] - t[1]) * 1000.0,
                ];
                match &mut current {
                    Some((i, at)) if *i == target_index => at.after_um = err,
                    _ => {
                        current = Some((
                            target_index,
                            TruthAt {
                                before_um: err,
                                after_um: err,
                            },
                        ))
                    }
                }
            }
        }
        Event::TargetDone { outcome, of } => {
            truth.push(current.take().map(|(_, at)| at));
            progress(outcome.index + 1, of);
        }
        Event::Homed => {}
    };
    let stage_name = devices.stage.info().name.clone();
    let camera_name = devices.camera.info().model.clone();
    let mut orch = Orchestrator {
        stage: devices.stage.as_mut(),
        camera: devices.camera.as_mut(),
        job,
    };
    let result = orch.run(&mut on_event).await;
    let (outcomes, error) = match result {
        Ok(o) => (o, None),
        Err(f) => (f.completed, Some(f.error.to_string())),
    };
    Report::build(
        &job.source,
        &stage_name,
        &camera_name,
        job.localize.method,
        job.targets.len(),
        &outcomes,
        &truth,
        started.elapsed().as_secs_f64(),
        error,
    )
}
