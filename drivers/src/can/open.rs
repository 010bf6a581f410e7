//! Opening a bus by its [`BusSpec`]: the backend this build has, or a clear error.

#[cfg(feature = "serial")]
use super::slcan;
#[cfg(all(target_os = "linux", feature = "socketcan"))]
use super::socketcan;
use super::{BusSpec, CanBus};
use crate::error::DriverError;

/// Open a bus (inside a tokio runtime).
pub async fn open_bus(spec: &BusSpec) -> Result<Box<dyn CanBus>, DriverError> {
    match spec {
        #[cfg(feature = "serial")]
        BusSpec::Slcan { port, bitrate } => {
            Ok(Box::new(slcan::SlcanBus::open(port, *bitrate).await?))
        }
        #[cfg(not(feature = "serial"))]
        BusSpec::Slcan { .. } => Err(DriverError::NotAvailable {
            backend: "slcan".into(),
            reason: "this build has no serial port support (cargo feature `serial`)".into(),
        }),
        BusSpec::SocketCan { interface } => open_socketcan(interface),
    }
}

#[cfg(all(target_os = "linux", feature = "socketcan"))]
fn open_socketcan(interface: &str) -> Result<Box<dyn CanBus>, DriverError> {
    Ok(Box::new(socketcan::SocketCanBus::open(interface)?))
}

#[cfg(not(all(target_os = "linux", feature = "socketcan")))]
fn open_socketcan(interface: &str) -> Result<Box<dyn CanBus>, DriverError> {
    Err(DriverError::NotAvailable {
        backend: format!("socketcan {interface}"),
        reason: if cfg!(target_os = "linux") {
            "this build has no SocketCAN support (cargo feature `socketcan`)".into()
        } else {
            "SocketCAN exists only on Linux".into()
        },
    })
}
