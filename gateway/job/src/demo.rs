//! The demo's rewrites of the embedded job (`gateway demo --stage … --camera …`): the
//! same simulated machine and camera, reached over a real bus protocol through the
//! emulator of that bus, so the pipeline talks to the real driver over real bytes.

use crate::canopen::{default_heartbeat, default_homing, default_sdo_timeout, options};
use crate::canopen::{CanopenLink, CanopenStageSpec};
use crate::modbus::{check_emulated, default_retries, default_timeout_ms, GENERIC_PROFILE};
use crate::modbus::{ModbusLink, ModbusStageSpec};
use crate::{CameraSpec, GrblLink, Job, StageSpec};
use link_spec::canopen::AxisConfig;
use link_spec::modbus::ModbusAxisConfig;
use link_spec::Axis;
use protocol::config::{ConfigDoc, ConfigError};
use protocol::modbus::DriveProfile;
use std::path::Path;
use std::sync::Arc;

/// A demo rewrite that does not apply to this job.
#[derive(Debug, thiserror::Error)]
pub enum DemoError {
    #[error("--stage {0} replaces the simulated stage of the demo job")]
    NotSimulated(&'static str),
    #[error("--camera gige serves the simulated camera of the demo job")]
    NotSimulatedCamera,
    #[error("{0}")]
    Mismatch(String),
    #[error(transparent)]
    Config(#[from] ConfigError),
}

/// Replace a simulated job's stage by the same machine behind the GRBL emulator
/// (`gateway demo --stage grbl`).
pub fn over_grbl(job: &mut Job) -> Result<(), DemoError> {
    match &job.stage {
        StageSpec::Sim { machine } => {
            job.stage = StageSpec::Grbl {
                link: GrblLink::Emulate(Box::new(machine.clone())),
                baud: 115_200,
            };
            Ok(())
        }
        StageSpec::Grbl { .. } => Ok(()),
        StageSpec::Modbus(_)
        | StageSpec::Canopen(_)
        | StageSpec::Linuxcnc(_)
        | StageSpec::Dnc(_) => Err(DemoError::NotSimulated("grbl")),
    }
}

/// Serve the job's simulated camera over GigE Vision (`gateway demo --camera gige`):
/// the emulator renders the same rig the stage moves, the GigE driver reads it.
pub fn over_gige(job: &mut Job) -> Result<(), DemoError> {
    let model = match &job.camera {
        CameraSpec::Sim { model } | CameraSpec::EmulatedGige { model, .. } => model.clone(),
        CameraSpec::Gige { .. } | CameraSpec::Replay { .. } => {
            return Err(DemoError::NotSimulatedCamera)
        }
    };
    job.camera = CameraSpec::EmulatedGige {
        model,
        // Loopback carries jumbo packets: fewer datagrams per frame.
        packet_size: 8192,
    };
    Ok(())
}

/// Replace a simulated job's stage by the same machine behind the Modbus drive
/// emulator with the generic profile, over TCP or RTU (`gateway demo --stage modbus`).
pub fn over_modbus(job: &mut Job, rtu: bool) -> Result<(), DemoError> {
    let StageSpec::Sim { machine } = &job.stage else {
        return Err(DemoError::NotSimulated("modbus"));
    };
    let doc = ConfigDoc::from_text(
        "config/drives/generic.toml (built in)",
        GENERIC_PROFILE,
        Path::new("config/drives"),
    );
    let profile = DriveProfile::from_doc(&doc)?;
    let axes = vec![
        ModbusAxisConfig {
            axis: Axis::X,
            unit: 1,
            min_mm: 0.0,
            max_mm: machine.axes.x.travel_mm,
            max_feed_mm_min: None,
        },
        ModbusAxisConfig {
            axis: Axis::Y,
            unit: 2,
            min_mm: 0.0,
            max_mm: machine.axes.y.travel_mm,
            max_feed_mm_min: None,
        },
    ];
    check_emulated(&profile, machine, &axes).map_err(DemoError::Mismatch)?;
    job.stage = StageSpec::Modbus(ModbusStageSpec {
        profile: Arc::new(profile),
        link: ModbusLink::Emulate {
            machine: Box::new(machine.clone()),
            rtu,
        },
        axes,
        timeout_ms: default_timeout_ms(),
        retries: default_retries(),
    });
    Ok(())
}

/// Replace a simulated job's stage by the same machine behind the CiA 402 drive
/// emulator on an SLCAN pseudo-terminal (`gateway demo --stage canopen`).
pub fn over_canopen(job: &mut Job) -> Result<(), DemoError> {
    let StageSpec::Sim { machine } = &job.stage else {
        return Err(DemoError::NotSimulated("canopen"));
    };
    let axis = |axis, node, a: &world::machine::AxisConfig| AxisConfig {
        axis,
        node,
        counts_per_mm: a.counts_per_mm,
        min_mm: 0.0,
        max_mm: a.travel_mm,
        max_feed_mm_min: a.max_feed_mm_min,
        accel_mm_s2: a.accel_mm_s2,
        homing_method: default_homing(),
    };
    let axes = vec![
        axis(Axis::X, 1, &machine.axes.x),
        axis(Axis::Y, 2, &machine.axes.y),
    ];
    job.stage = StageSpec::Canopen(CanopenStageSpec {
        link: CanopenLink::Emulate {
            machine: Box::new(machine.clone()),
            eds: None,
        },
        axes,
        options: options(default_heartbeat(), default_sdo_timeout()),
    });
    Ok(())
}
