//! The `aravis` camera backend: any GenICam camera Aravis 0.8 can open (GigE Vision,
//! USB3 Vision), through the `aravis` crate, behind cargo feature `aravis` (the system
//! library, Debian `libaravis-dev`, is needed to build it). Without the feature,
//! [`AravisCamera::open`] returns `DriverError::NotAvailable` saying how to get it; the
//! pure-Rust `gige` backend needs nothing and is what the tests use against our emulator.
//!
//! Aravis calls block, so each runs on tokio's blocking pool; the camera is in software
//! trigger mode and every grab triggers one frame, pops one buffer within a bounded
//! timeout, checks its status (a buffer that is not `Success` — missing packets, timeout,
//! size mismatch — is an error, never a frame), its size and pixel format, copies the
//! image and pushes the buffer back so the stream never starves.

#[cfg(feature = "aravis")]
pub use imp::AravisCamera;

#[cfg(not(feature = "aravis"))]
pub use off::AravisCamera;

#[cfg(not(feature = "aravis"))]
mod off {
    use crate::camera::{Camera, CameraInfo, Frame};
    use crate::error::DriverError;
    use async_trait::async_trait;
    use std::time::Duration;

    /// Placeholder of the Aravis backend in a build without the `aravis` feature.
    pub struct AravisCamera {
        info: CameraInfo,
    }

    impl AravisCamera {
        /// Always `NotAvailable` in this build.
        pub async fn open(
            name: Option<&str>,
            _frame_timeout: Duration,
        ) -> Result<Self, DriverError> {
            Err(DriverError::NotAvailable {
                backend: "aravis".into(),
                reason: format!(
                    "camera `{}`: this build has no Aravis support; rebuild with `--features drivers/aravis` \
                     (needs the system library: apt-get install libaravis-dev), or use the pure-Rust `gige` backend",
                    name.unwrap_or("first found")
                ),
            })
        }
    }

    #[async_trait]
    impl Camera for AravisCamera {
        fn info(&self) -> &CameraInfo {
            &self.info
        }
        async fn grab(&mut self) -> Result<Frame, DriverError> {
            unreachable!("an AravisCamera cannot be opened without the `aravis` feature")
        }
    }
}

#[cfg(feature = "aravis")]
mod imp {
    use crate::camera::{Camera, CameraInfo, Frame, FrameMeta};
    use crate::error::DriverError;
    use aravis::prelude::*;
    use aravis::{AcquisitionMode, BufferStatus, PixelFormat};
    use async_trait::async_trait;
    use protocol::{MonoImage, Pixels};
    use std::sync::OnceLock;
    use std::time::Duration;

    static INIT: OnceLock<bool> = OnceLock::new();

    fn glib_err(device: &str, what: &str, e: impl std::fmt::Display) -> DriverError {
        DriverError::Transport {
            device: device.into(),
            message: format!("{what}: {e}"),
        }
    }

    struct Inner {
        camera: aravis::Camera,
        stream: aravis::Stream,
    }

    /// A camera opened through Aravis, in software-trigger acquisition.
    pub struct AravisCamera {
        inner: Option<Inner>,
        info: CameraInfo,
        device: String,
        pixel_format: PixelFormat,
        frame_timeout: Duration,
        sequence: u64,
    }

    async fn blocking<T: Send + 'static>(
        device: &str,
        f: impl FnOnce() -> T + Send + 'static,
    ) -> Result<T, DriverError> {
        tokio::task::spawn_blocking(f)
            .await
            .map_err(|e| DriverError::Transport {
                device: device.into(),
                message: format!("Aravis call panicked: {e}"),
            })
    }

    impl AravisCamera {
        /// Opens `name` (Aravis device id `vendor-model-serial`, an IP address, a MAC...;
        /// None: the first camera found).
        pub async fn open(
            name: Option<&str>,
            frame_timeout: Duration,
        ) -> Result<Self, DriverError> {
            INIT.get_or_init(|| aravis::Aravis::initialize().is_ok());
            let device = format!("Aravis camera {}", name.unwrap_or("(first found)"));
            let n = name.map(str::to_string);
            let d = device.clone();
            let r = blocking(&device, move || -> Result<_, DriverError> {
                let camera =
                    aravis::Camera::new(n.as_deref()).map_err(|e| DriverError::NotAvailable {
                        backend: "aravis".into(),
                        reason: format!("{d}: {e}"),
                    })?;
                let pf = camera
                    .pixel_format()
                    .map_err(|e| glib_err(&d, "PixelFormat", e))?;
                let bit_depth = if pf == PixelFormat::MONO_8 {
                    8
                } else if pf == PixelFormat::MONO_16 {
                    16
                } else {
                    return Err(DriverError::Unsupported {
                        device: d.clone(),
                        message: format!("pixel format {pf:?}: this driver takes Mono8 or Mono16"),
                    });
                };
                let (_, _, w, h) = camera.region().map_err(|e| glib_err(&d, "region", e))?;
                camera
                    .set_acquisition_mode(AcquisitionMode::Continuous)
                    .map_err(|e| glib_err(&d, "AcquisitionMode", e))?;
                camera
                    .set_trigger("Software")
                    .map_err(|e| glib_err(&d, "TriggerSource Software", e))?;
                let stream = camera
                    .create_stream()
                    .map_err(|e| glib_err(&d, "create_stream", e))?;
                let payload = camera
                    .payload()
                    .map_err(|e| glib_err(&d, "PayloadSize", e))?
                    as usize;
                for _ in 0..4 {
                    stream.push_buffer(aravis::Buffer::new_allocate(payload));
                }
                camera
                    .start_acquisition()
                    .map_err(|e| glib_err(&d, "AcquisitionStart", e))?;
                let info = CameraInfo {
                    model: camera
                        .model_name()
                        .map(|s| s.to_string())
                        .unwrap_or_default(),
                    serial: camera
                        .device_serial_number()
                        .map(|s| s.to_string())
                        .unwrap_or_default(),
                    width: w as u32,
                    height: h as u32,
                    bit_depth,
                };
                Ok((Inner { camera, stream }, info, pf))
            })
            .await??;
            let (inner, info, pixel_format) = r;
            Ok(Self {
                inner: Some(inner),
                info,
                device,
                pixel_format,
                frame_timeout,
                sequence: 0,
            })
        }
    }

    #[async_trait]
    impl Camera for AravisCamera {
        fn info(&self) -> &CameraInfo {
            &self.info
        }

        async fn grab(&mut self) -> Result<Frame, DriverError> {
            let inner = self.inner.take().ok_or_else(|| DriverError::InvalidState {
                device: self.device.clone(),
                message: "an earlier grab was interrupted; reopen the camera".into(),
            })?;
            let d = self.device.clone();
            let timeout_us = self.frame_timeout.as_micros() as u64;
            let (w, h, pf) = (self.info.width, self.info.height, self.pixel_format);
            let (inner, r) = blocking(&self.device, move || {
                let r = (|| -> Result<(MonoImage, u64, f64, f64), DriverError> {
                    inner.camera.software_trigger().map_err(|e| glib_err(&d, "TriggerSoftware", e))?;
                    let buf = inner.stream.timeout_pop_buffer(timeout_us).ok_or_else(|| DriverError::Timeout {
                        device: d.clone(),
                        what: "a frame after TriggerSoftware".into(),
                        after_ms: timeout_us / 1000,
                    })?;
                    let status = buf.status();
                    let checked = if status != BufferStatus::Success {
                        Err(DriverError::Protocol {
                            device: d.clone(),
                            message: format!("buffer status {status:?} (incomplete or corrupt frame); frame refused"),
                        })
                    } else if buf.image_width() as u32 != w || buf.image_height() as u32 != h || buf.image_pixel_format() != pf {
                        Err(DriverError::Protocol {
                            device: d.clone(),
                            message: format!(
                                "frame is {}x{} {:?} but the camera declared {w}x{h} {pf:?}; frame refused",
                                buf.image_width(),
                                buf.image_height(),
                                buf.image_pixel_format()
                            ),
                        })
                    } else {
                        let data = buf.image_data();
                        let pixels = if pf == PixelFormat::MONO_8 {
                            Pixels::Mono8(data)
                        } else {
                            Pixels::Mono16(data.chunks_exact(2).map(|c| u16::from_le_bytes([c[0], c[1]])).collect())
                        };
                        MonoImage::new(w, h, pixels)
                            .map_err(|e| DriverError::Protocol { device: d.clone(), message: e.to_string() })
                            .map(|img| (img, buf.timestamp()))
                    };
                    // Every popped buffer goes back, failed ones too, or the stream starves.
                    inner.stream.push_buffer(buf);
                    let (img, ts) = checked?;
                    let exposure = inner.camera.exposure_time().unwrap_or(f64::NAN);
                    let gain = inner.camera.gain().unwrap_or(f64::NAN);
                    Ok((img, ts, exposure, gain))
                })();
                (inner, r)
            })
            .await?;
            self.inner = Some(inner);
            let (image, timestamp_ns, exposure_us, gain_db) = r?;
            let meta = FrameMeta {
                sequence: self.sequence,
                timestamp_ns,
                exposure_us,
                gain_db,
            };
            self.sequence += 1;
            Ok(Frame { image, meta })
        }
    }

    impl Drop for AravisCamera {
        fn drop(&mut self) {
            if let Some(i) = &self.inner {
                let _ = i.camera.stop_acquisition();
            }
        }
    }
}
