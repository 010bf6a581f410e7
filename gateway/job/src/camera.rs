//! The `[camera]` of a job: one typed link per way frames can reach the gateway, real
//! or emulated, and the check that the camera can see the machine.
//!
//! ```toml
//! [camera]
//! driver = "sim"                      # in-process simulated camera: `model`
//! # driver = "gige" + camera = "192.168.0.30" | "Vendor-Model-SERIAL"   (a real camera)
//! # driver = "gige" + model = "../cameras/mono-1.3mp.toml"  (the GigE Vision emulator)
//! # driver = "replay" + folder = "frames/"                   (PNG files, name order)
//! model = "../cameras/mono-1.3mp.toml"
//! pixel_axes = "+x,-y"
//! um_per_px = 4.0
//! ```

use protocol::config::{ConfigDoc, ConfigError};
use serde::Deserialize;
use std::path::PathBuf;
use world::camera::CameraModel;

/// How frames reach the gateway.
#[derive(Clone, Debug, PartialEq)]
pub enum CameraSpec {
    /// The in-process simulated camera (optics `model`) on the simulated machine.
    Sim { model: CameraModel },
    /// The GigE Vision emulator on a loopback port serving the simulated camera (optics
    /// `model`) of the simulated machine, read by the GigE Vision driver.
    EmulatedGige {
        model: CameraModel,
        packet_size: u32,
    },
    /// A real GigE Vision camera: an address (`ip`, `ip:port`) or a device name
    /// (`vendor-model-serial`, serial or user name, found by discovery).
    Gige { device: String, packet_size: u32 },
    /// PNG frames from a folder, in file-name order, sizes checked.
    Replay { folder: PathBuf },
}

/// Stream packet size when the job gives none: plain Ethernet.
pub const DEFAULT_PACKET_SIZE: u32 = 1500;

impl CameraSpec {
    /// Whether this camera is the simulated one (in-process or emulated), which can only
    /// look at a simulated machine.
    pub fn is_simulated(&self) -> bool {
        matches!(
            self,
            CameraSpec::Sim { .. } | CameraSpec::EmulatedGige { .. }
        )
    }

    /// The optics of a simulated camera (None for a real camera or replayed frames,
    /// whose optics the job does not describe).
    pub fn model(&self) -> Option<&CameraModel> {
        match self {
            CameraSpec::Sim { model } | CameraSpec::EmulatedGige { model, .. } => Some(model),
            CameraSpec::Gige { .. } | CameraSpec::Replay { .. } => None,
        }
    }

    /// A camera that cannot see the machine: a simulated camera needs a simulated
    /// machine, a real camera a real one (replayed frames go with either).
    pub fn check_pairing(&self, machine_simulated: bool) -> Result<(), PairingError> {
        match (self, machine_simulated) {
            (CameraSpec::Sim { .. }, false) => Err(PairingError::SimulatedCamera),
            (CameraSpec::EmulatedGige { .. }, false) => Err(PairingError::EmulatedGige),
            (CameraSpec::Gige { device, .. }, true) => {
                Err(PairingError::RealCamera(device.clone()))
            }
            _ => Ok(()),
        }
    }
}

/// A camera and a machine that cannot see each other. Checked before anything opens.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PairingError {
    #[error("sim camera not available: a simulated camera cannot see a real machine: use `emulate` for the demo, or a real camera")]
    SimulatedCamera,
    #[error("gige (emulated) not available: the GigE Vision emulator needs a simulated machine to look at")]
    EmulatedGige,
    #[error("gige not available: a real camera (`{0}`) cannot see a simulated machine: use a real stage, or leave out `camera` to emulate the camera")]
    RealCamera(String),
}

/// `[camera]` as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawCamera {
    driver: String,
    /// `sim`: the simulated camera's optics file. `gige`: the optics the GigE Vision
    /// emulator serves (when `camera` is not given).
    model: Option<String>,
    /// `gige`: a real camera's address (`ip`, `ip:port`) or device name.
    camera: Option<String>,
    /// `gige`: stream packet size, bytes (default 1500; jumbo frames allow up to 9000).
    packet_size: Option<u32>,
    /// `replay`: the folder of PNG frames.
    folder: Option<String>,
    #[serde(default)]
    pub(crate) pixel_axes: Option<String>,
    pub(crate) um_per_px: Option<f64>,
}

impl RawCamera {
    /// Check and resolve (errors name the job file, line and key).
    pub(crate) fn resolve(&self, doc: &ConfigDoc) -> Result<CameraSpec, ConfigError> {
        let model = |rel: &str| CameraModel::from_doc(&doc.read_relative("camera.model", rel)?);
        match self.driver.as_str() {
            "sim" => {
                let Some(rel) = &self.model else {
                    return Err(doc.invalid(
                        "camera.model",
                        "the sim camera needs `model`, its optics file",
                    ));
                };
                self.refuse(
                    doc,
                    &[
                        ("camera", &self.camera.is_some()),
                        ("packet_size", &self.packet_size.is_some()),
                        ("folder", &self.folder.is_some()),
                    ],
                )?;
                Ok(CameraSpec::Sim { model: model(rel)? })
            }
            "gige" => {
                let packet_size = self.packet_size.unwrap_or(DEFAULT_PACKET_SIZE);
                if !(576..=16_000).contains(&packet_size) {
                    return Err(doc.invalid(
                        "camera.packet_size",
                        "must be 576..16000 bytes (1500 on plain Ethernet, up to 9000 with jumbo frames)",
                    ));
                }
                self.refuse(doc, &[("folder", &self.folder.is_some())])?;
                match (&self.model, &self.camera) {
                    (Some(_), Some(_)) => Err(doc.invalid(
                        "camera.camera",
                        "give `camera` (a real camera) or `model` (the optics to emulate), not both",
                    )),
                    (None, None) => Err(doc.invalid(
                        "camera.camera",
                        "the gige camera needs `camera` (address or device name) or `model` (optics file to emulate)",
                    )),
                    (Some(rel), None) => Ok(CameraSpec::EmulatedGige {
                        model: model(rel)?,
                        packet_size,
                    }),
                    (None, Some(device)) => Ok(CameraSpec::Gige {
                        device: device.clone(),
                        packet_size,
                    }),
                }
            }
            "replay" => {
                let Some(folder) = &self.folder else {
                    return Err(doc.invalid(
                        "camera.folder",
                        "the replay camera needs `folder`, a folder of PNG frames",
                    ));
                };
                self.refuse(
                    doc,
                    &[
                        ("model", &self.model.is_some()),
                        ("camera", &self.camera.is_some()),
                        ("packet_size", &self.packet_size.is_some()),
                    ],
                )?;
                Ok(CameraSpec::Replay {
                    folder: doc.resolve(folder),
                })
            }
            other => Err(doc.invalid(
                "camera.driver",
                format!("unknown camera driver `{other}`; this build knows: sim, gige, replay"),
            )),
        }
    }

    /// Keys given that this driver does not use: refused, not silently ignored.
    fn refuse(&self, doc: &ConfigDoc, keys: &[(&str, &bool)]) -> Result<(), ConfigError> {
        match keys.iter().find(|(_, given)| **given) {
            Some((key, _)) => Err(doc.invalid(
                &format!("camera.{key}"),
                format!("the {} camera does not use `{key}`", self.driver),
            )),
            None => Ok(()),
        }
    }
}
