//! The factory: a [`StageLink`] or [`CameraLink`] in, an open device out. The one place
//! that matches on a link family, so callers (the gateway's device opener, the service
//! later) never re-match a spec. A backend this build lacks is refused here with a clear
//! error naming the build feature.

use crate::camera::Camera;
use crate::error::DriverError;
use crate::prober::{Prober, ProberError, StageProber};
use crate::stage::{Axis, Stage};
use link_spec::{CameraLink, StageLink};

#[cfg(any(not(feature = "serial"), not(feature = "modbus")))]
fn not_built(backend: &str, feature: &str) -> DriverError {
    DriverError::NotAvailable {
        backend: backend.into(),
        reason: format!("this build of the drivers has no `{feature}` feature"),
    }
}

/// Open the stage a link names. Must run inside the tokio runtime that will use it (bus
/// tasks are tasks of that runtime).
pub async fn open_stage(link: &StageLink) -> Result<Box<dyn Stage>, DriverError> {
    match link {
        #[cfg(feature = "serial")]
        StageLink::Grbl {
            port,
            baud,
            options,
        } => Ok(Box::new(
            crate::grbl::GrblStage::open(port, *baud, options.clone()).await?,
        )),
        #[cfg(not(feature = "serial"))]
        StageLink::Grbl { .. } => Err(not_built("GRBL on a serial port", "serial")),
        #[cfg(feature = "modbus")]
        StageLink::Modbus {
            endpoint,
            options,
            profile,
            axes,
        } => Ok(Box::new(
            crate::modbus::open_stage(endpoint.clone(), options.clone(), profile.clone(), axes)
                .await?,
        )),
        #[cfg(not(feature = "modbus"))]
        StageLink::Modbus { .. } => Err(not_built("Modbus drives", "modbus")),
        StageLink::Canopen { bus, options, axes } => {
            let bus = crate::can::open_bus(bus).await?;
            // The stage keeps the network's bus task alive; the handle is not needed.
            let (stage, _network) =
                crate::canopen::open_stage(bus, axes.clone(), options.clone()).await?;
            Ok(Box::new(stage))
        }
        StageLink::Linuxcnc {
            address,
            options,
            axes,
        } => Ok(Box::new(
            crate::linuxcnc::LinuxcncStage::open(address, options.clone(), axes.clone()).await?,
        )),
        #[cfg(feature = "serial")]
        StageLink::Dnc {
            port,
            baud,
            options,
            axes,
        } => Ok(Box::new(
            crate::dnc::DncStage::open(port, *baud, options.clone(), axes.clone()).await?,
        )),
        #[cfg(not(feature = "serial"))]
        StageLink::Dnc { .. } => Err(not_built("a tape port (DNC) on a serial port", "serial")),
    }
}

/// Open the stage a link names as a [`Prober`]: refused, before anything moves, when
/// its capabilities lack probing moves or one of `rotary_axes` (the stage is closed
/// again).
pub async fn open_prober(
    link: &StageLink,
    rotary_axes: &[Axis],
) -> Result<Box<dyn Prober>, ProberError> {
    let stage = open_stage(link).await?;
    Ok(Box::new(StageProber::new(stage, rotary_axes)?))
}

/// Open the camera a link names.
pub async fn open_camera(link: &CameraLink) -> Result<Box<dyn Camera>, DriverError> {
    match link {
        CameraLink::Gige { device, options } => Ok(Box::new(
            crate::gige::GigeCamera::open(device, options.clone()).await?,
        )),
        CameraLink::Aravis {
            name,
            frame_timeout,
        } => Ok(Box::new(
            crate::aravis::AravisCamera::open(name.as_deref(), *frame_timeout).await?,
        )),
    }
}

#[cfg(feature = "serial")]
/// Open a GRBL controller's port as a raw line (the pass-through forwards the sender's
/// bytes itself) and wait for its banner line (an Arduino resets when its
/// port opens and talks after about two seconds; a controller that was already running
/// says nothing, so `banner_wait` bounds the wait). What it said at start-up (with a
/// first power-up's `error:7` and settings dump) is not the sender's and is returned,
/// not passed on.
pub async fn open_grbl_line(
    port: &str,
    baud: u32,
    banner_wait: std::time::Duration,
) -> std::io::Result<(tokio_serial::SerialStream, String)> {
    use std::io;
    use tokio::io::AsyncReadExt;
    use tokio_serial::SerialPortBuilderExt;
    let mut controller = tokio_serial::new(port, baud)
        .open_native_async()
        .map_err(|e| io::Error::other(format!("opening the controller at {port}: {e}")))?;
    let mut banner = Vec::new();
    let mut buf = [0u8; 256];
    let deadline = tokio::time::Instant::now() + banner_wait;
    // Up to the end of the banner's line: a boot prints more before it (a first
    // power-up's `error:7` and settings), none of it the sender's.
    let complete_banner = |bytes: &[u8]| {
        let mut lines: Vec<&[u8]> = bytes.split(|b| *b == b'\n').collect();
        lines.pop(); // not ended yet
        lines.iter().any(|l| {
            matches!(
                protocol::grbl::response::Response::parse(
                    String::from_utf8_lossy(l).trim_end_matches('\r')
                ),
                protocol::grbl::response::Response::Banner { .. }
            )
        })
    };
    while !complete_banner(&banner) {
        match tokio::time::timeout_at(deadline, controller.read(&mut buf)).await {
            Ok(Ok(n)) if n > 0 => banner.extend_from_slice(&buf[..n]),
            Ok(Ok(_)) => return Err(io::Error::other(format!("the controller at {port} closed"))),
            Ok(Err(e)) => return Err(e),
            Err(_) => break,
        }
    }
    Ok((
        controller,
        String::from_utf8_lossy(&banner).trim().to_string(),
    ))
}
