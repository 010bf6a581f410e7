//! The demo's links: the embedded demo job (a simulated C5 stage, camera and certified
//! board) with its stage or camera reached over a real bus protocol through that bus's
//! emulator (`job::demo::over_*`), so the pipeline talks to the real driver over real
//! bytes. The compensation itself is `compensate`'s.

use crate::request::RequestError;
use job::demo::DemoError;
use job::Job;

/// The stage links the demo knows.
pub const STAGES: &[&str] = &["sim", "grbl", "modbus", "canopen"];
/// The Modbus transports (with the `modbus` stage).
pub const TRANSPORTS: &[&str] = &["tcp", "rtu"];
/// The camera links the demo knows.
pub const CAMERAS: &[&str] = &["sim", "gige"];

/// The demo job over the chosen links: `stage` one of [`STAGES`] (`sim` in-process,
/// `grbl` the GRBL emulator on a pseudo-terminal, `modbus` the drive emulator over
/// `transport` `tcp` or `rtu`, `canopen` the CiA 402 emulator behind an SLCAN adapter),
/// `camera` one of [`CAMERAS`] (`sim` in-process, `gige` the GigE Vision emulator on a
/// loopback port). An unknown name, or a link the job cannot take, is refused naming
/// the field (`stage`, `transport`, `camera`).
pub fn demo_job(stage: &str, transport: &str, camera: &str) -> Result<Job, RequestError> {
    let mut job = Job::demo();
    let failed = |field: &'static str| move |e: DemoError| RequestError::new(field, e.to_string());
    match camera {
        "sim" => {}
        "gige" => job::demo::over_gige(&mut job).map_err(failed("camera"))?,
        other => {
            return Err(RequestError::new(
                "camera",
                format!("`{other}`: this build knows sim and gige"),
            ))
        }
    }
    // The transport applies to the Modbus stage only, but a misspelt one is refused
    // whatever the stage.
    if !TRANSPORTS.contains(&transport) {
        return Err(RequestError::new(
            "transport",
            format!("`{transport}`: expected tcp or rtu"),
        ));
    }
    match stage {
        "sim" => {}
        "grbl" => job::demo::over_grbl(&mut job).map_err(failed("stage"))?,
        "modbus" => {
            job::demo::over_modbus(&mut job, transport == "rtu").map_err(failed("stage"))?
        }
        "canopen" => job::demo::over_canopen(&mut job).map_err(failed("stage"))?,
        other => {
            return Err(RequestError::new(
                "stage",
                format!("`{other}`: this build knows sim, grbl, modbus and canopen"),
            ))
        }
    }
    Ok(job)
}

#[cfg(test)]
mod tests {
    use super::*;
    use job::{CameraSpec, StageSpec};

    #[test]
    fn the_links_are_chosen_by_name() {
        let job = demo_job("sim", "tcp", "sim").unwrap();
        assert!(matches!(job.stage, StageSpec::Sim { .. }));
        assert!(matches!(job.camera, CameraSpec::Sim { .. }));
        let job = demo_job("grbl", "tcp", "gige").unwrap();
        assert!(matches!(job.stage, StageSpec::Grbl { .. }));
        assert!(matches!(job.camera, CameraSpec::EmulatedGige { .. }));
        for transport in TRANSPORTS {
            let job = demo_job("modbus", transport, "sim").unwrap();
            assert!(matches!(job.stage, StageSpec::Modbus(_)));
        }
        let job = demo_job("canopen", "tcp", "sim").unwrap();
        assert!(matches!(job.stage, StageSpec::Canopen(_)));
    }

    #[test]
    fn an_unknown_link_is_refused_naming_the_field() {
        let e = demo_job("ethercat", "tcp", "sim").unwrap_err();
        assert_eq!(e.field, "stage");
        assert_eq!(
            e.for_cli(),
            "--stage: `ethercat`: this build knows sim, grbl, modbus and canopen"
        );
        let e = demo_job("modbus", "udp", "sim").unwrap_err();
        assert_eq!(e.field, "transport");
        assert_eq!(e.flag(), "--transport");
        let e = demo_job("sim", "tcp", "usb").unwrap_err();
        assert_eq!(e.field, "camera");
    }
}
