//! Modbus TCP and RTU positioning drives (tokio-modbus), one drive per axis, register
//! maps from drive profiles (`config/drives/*.toml`, [`protocol::modbus::profile`]).
//!
//! * [`ModbusBus`]: one TCP connection or RTU line, shared by the units on it; every
//!   request bounded, the connection rebuilt after a failure so late replies are never
//!   taken for new ones, lost replies retried within bounds.
//! * [`ModbusAxis`]: an [`AxisDrive`](crate::AxisDrive) through a profile; moves are
//!   triggered exactly once even when a reply is lost (read-back before any resend).
//! * [`open_stage`]: the axes of a machine made into a [`MultiAxisStage`].

mod axis;
mod bus;

pub use axis::{ModbusAxis, ModbusAxisConfig, MoveStats};
pub use bus::{
    exception_error, BusStats, Endpoint, Failure, ModbusBus, ModbusOptions, Op, Parity, SharedBus,
};

use crate::error::DriverError;
use crate::multi_axis::{AxisDrive, MultiAxisStage};
use protocol::modbus::profile::DriveProfile;
use std::sync::Arc;

/// Connect to the drives of `axes` on one endpoint and make them a stage. Each unit
/// must answer a status read, so a wrong unit id or profile fails here, naming it.
pub async fn open_stage(
    endpoint: Endpoint,
    opts: ModbusOptions,
    profile: Arc<DriveProfile>,
    axes: &[ModbusAxisConfig],
) -> Result<MultiAxisStage, DriverError> {
    let bus = ModbusBus::new(endpoint.clone(), opts).shared();
    bus.lock().await.connect().await?;
    let mut drives: Vec<Box<dyn AxisDrive>> = Vec::new();
    for cfg in axes {
        let mut axis = ModbusAxis::new(bus.clone(), profile.clone(), cfg).await;
        axis.status().await?;
        drives.push(Box::new(axis));
    }
    MultiAxisStage::new(&format!("{endpoint} ({})", profile.name), drives)
}
