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
