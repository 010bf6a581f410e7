//! Why the devices of a job could not be opened.

use drivers::DriverError;
use job::PairingError;

/// Why the devices of a job could not be opened.
#[derive(Debug, thiserror::Error)]
pub enum OpenError {
    /// The camera cannot see the machine; nothing was opened.
    #[error(transparent)]
    Pairing(#[from] PairingError),
    /// A device, its link or an in-process emulator failed.
    #[error(transparent)]
    Driver(#[from] DriverError),
    /// An emulator this process was to run could not start (no pseudo-terminal, no
    /// loopback port, a drive description it cannot serve).
    #[error("cannot start the {what}: {message}")]
    Emulator { what: &'static str, message: String },
    /// [`open_devices`] was asked for links that open inside an async runtime.
    #[error("this job's stage or camera connects over a link (serial, CAN, Modbus, GigE Vision), which is opened inside the async runtime: use devices::open_devices_async")]
    NeedsRuntime,
}
