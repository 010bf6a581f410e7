//! Opening the camera of a job: the in-process simulated camera, GigE Vision (a real
//! camera by address or device name, or the GigE Vision emulator serving the simulated
//! camera on a loopback port and sharing the rig with the stage) or the replay of PNG
//! files from a folder. The camera is opened after the stage, from the rig the stage
//! gave (if any), so every stage link works with every camera link.

use crate::error::OpenError;
use async_trait::async_trait;
use drivers::gige::GigeOptions;
use drivers::sim::SimCamera;
use drivers::{Camera, CameraInfo, CameraLink, DriverError, Frame, FrameMeta};
use emulators::gige::{GigeCameraServer, GigeServerOptions};
use job::CameraSpec;
use std::path::{Path, PathBuf};
use vision::image_io::load_png;
use world::SharedRig;

/// Open the camera of a job: `rig` is the simulated machine when the stage is
/// simulated (directly or behind an emulated bus), None for a real machine.
pub async fn open_camera(
    spec: &CameraSpec,
    rig: Option<&SharedRig>,
) -> Result<Box<dyn Camera>, OpenError> {
    spec.check_pairing(rig.is_some())?;
    let gige = |device: String, packet_size: u32| CameraLink::Gige {
        device,
        options: GigeOptions {
            packet_size,
            ..Default::default()
        },
    };
    Ok(match (spec, rig) {
        (CameraSpec::Sim { .. }, Some(rig)) => Box::new(SimCamera::new(rig.clone())),
        (CameraSpec::EmulatedGige { packet_size, .. }, Some(rig)) => {
            let server = GigeCameraServer::spawn(rig.clone(), GigeServerOptions::default())
                .await
                .map_err(|e| OpenError::Emulator {
                    what: "GigE Vision emulator",
                    message: format!("cannot bind a loopback UDP port: {e}"),
                })?;
            let link = gige(server.control_addr().to_string(), *packet_size);
            let camera = drivers::open_camera(&link).await?;
            Box::new(EmulatedGige {
                camera,
                _server: server,
            })
        }
        (
            CameraSpec::Gige {
                device,
                packet_size,
            },
            None,
        ) => drivers::open_camera(&gige(device.clone(), *packet_size)).await?,
        (CameraSpec::Replay { folder }, _) => Box::new(ReplayCamera::open(folder)?),
        // The pairings `check_pairing` refuses.
        (CameraSpec::Sim { .. } | CameraSpec::EmulatedGige { .. } | CameraSpec::Gige { .. }, _) => {
            unreachable!("checked above")
        }
    })
}

/// The GigE driver connected to the in-process emulator, which lives as long as it.
pub struct EmulatedGige {
    camera: Box<dyn Camera>,
    _server: GigeCameraServer,
}

#[async_trait]
impl Camera for EmulatedGige {
    fn info(&self) -> &CameraInfo {
        self.camera.info()
    }
    async fn grab(&mut self) -> Result<Frame, DriverError> {
        self.camera.grab().await
    }
}

/// Frames replayed from PNG files (8- or 16-bit greyscale) in a folder, in file-name
/// order: re-running the pipeline on recorded frames. Every file must have the size and
/// bit depth of the first; running out of files is an error, never a repeat.
pub struct ReplayCamera {
    files: Vec<PathBuf>,
    next: usize,
    info: CameraInfo,
    device: String,
}

impl ReplayCamera {
    pub fn open(folder: &Path) -> Result<Self, DriverError> {
        let device = format!("replay camera ({})", folder.display());
        let unavailable = |reason: String| DriverError::NotAvailable {
            backend: "replay".into(),
            reason,
        };
        let rd = std::fs::read_dir(folder).map_err(|e| {
            unavailable(format!("{}: cannot read the folder: {e}", folder.display()))
        })?;
        let mut files: Vec<PathBuf> = rd
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|x| x.eq_ignore_ascii_case("png")))
            .collect();
        files.sort();
        let first = files
            .first()
            .ok_or_else(|| unavailable(format!("{}: no .png files", folder.display())))?;
        let img = load_png(first).map_err(|e| unavailable(e.to_string()))?;
        Ok(Self {
            info: CameraInfo {
                model: "PNG replay".into(),
                serial: folder.display().to_string(),
                width: img.width,
                height: img.height,
                bit_depth: img.bit_depth(),
            },
            files,
            next: 0,
            device,
        })
    }

    /// Files left to replay.
    pub fn remaining(&self) -> usize {
        self.files.len() - self.next
    }
}

#[async_trait]
impl Camera for ReplayCamera {
    fn info(&self) -> &CameraInfo {
        &self.info
    }

    async fn grab(&mut self) -> Result<Frame, DriverError> {
        let Some(path) = self.files.get(self.next) else {
            return Err(DriverError::InvalidState {
                device: self.device.clone(),
                message: format!("all {} frames have been replayed", self.files.len()),
            });
        };
        // A refused file is consumed too: the next grab moves on.
        self.next += 1;
        let image = load_png(path).map_err(|e| DriverError::Protocol {
            device: self.device.clone(),
            message: e.to_string(),
        })?;
        if (image.width, image.height, image.bit_depth())
            != (self.info.width, self.info.height, self.info.bit_depth)
        {
            return Err(DriverError::Protocol {
                device: self.device.clone(),
                message: format!(
                    "{}: {}x{} {}-bit, but the first frame was {}x{} {}-bit; frame refused",
                    path.display(),
                    image.width,
                    image.height,
                    image.bit_depth(),
                    self.info.width,
                    self.info.height,
                    self.info.bit_depth
                ),
            });
        }
        let sequence = self.next as u64 - 1;
        Ok(Frame {
            image,
            meta: FrameMeta {
                sequence,
                timestamp_ns: 0,
                exposure_us: f64::NAN,
                gain_db: f64::NAN,
            },
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use protocol::{MonoImage, Pixels};
    use vision::image_io::save_png;

    #[test]
    fn replay_plays_files_in_order_checks_sizes_and_ends() {
        let dir = std::env::temp_dir().join(format!("replay-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let img = |w, v| MonoImage::new(w, 3, Pixels::Mono8(vec![v; w as usize * 3])).unwrap();
        save_png(&img(4, 1), &dir.join("a.png")).unwrap();
        save_png(&img(4, 2), &dir.join("b.png")).unwrap();
        save_png(&img(5, 3), &dir.join("c.png")).unwrap();
        std::fs::write(dir.join("notes.txt"), "not a frame").unwrap();
        let rt = tokio::runtime::Builder::new_current_thread()
            .build()
            .unwrap();
        let mut cam = ReplayCamera::open(&dir).unwrap();
        assert_eq!((cam.info().width, cam.info().bit_depth), (4, 8));
        assert_eq!(cam.remaining(), 3);
        let f = rt.block_on(cam.grab()).unwrap();
        assert_eq!((f.meta.sequence, f.image.get(0, 0)), (0, 1));
        assert_eq!(rt.block_on(cam.grab()).unwrap().image.get(0, 0), 2);
        let e = rt.block_on(cam.grab()).unwrap_err().to_string();
        assert!(
            e.contains("c.png") && e.contains("5x3") && e.contains("frame refused"),
            "{e}"
        );
        let e = rt.block_on(cam.grab()).unwrap_err().to_string();
        assert!(e.contains("all 3 frames have been replayed"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
        let e = ReplayCamera::open(&dir).err().unwrap().to_string();
        assert!(e.contains("cannot read the folder"), "{e}");
    }
}
