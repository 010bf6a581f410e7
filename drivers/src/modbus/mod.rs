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
    for cfg in axes {
        crate::stage::check_axis_config(
            &format!("{endpoint} unit {}", cfg.unit),
            &format!("axis {}", cfg.axis),
            cfg.min_mm,
            cfg.max_mm,
            cfg.max_feed_mm_min,
        )?;
    }
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

#[cfg(test)]
mod tests {
    use super::*;
    use link_spec::Axis;

    #[tokio::test]
    async fn an_axis_max_feed_that_is_not_a_positive_number_is_refused_before_connecting() {
        let text = include_str!("../../../config/drives/generic.toml");
        let profile = DriveProfile::from_doc(&protocol::config::ConfigDoc::from_text(
            "generic.toml",
            text,
            std::path::Path::new("."),
        ))
        .unwrap();
        // Nothing listens there: a connection attempt would fail differently.
        let endpoint = Endpoint::Tcp("127.0.0.1:9".parse().unwrap());
        for feed in [f64::NAN, 0.0, -5.0, f64::INFINITY] {
            let axes = [ModbusAxisConfig {
                axis: Axis::X,
                unit: 1,
                min_mm: 0.0,
                max_mm: 100.0,
                max_feed_mm_min: Some(feed),
            }];
            let e = open_stage(
                endpoint.clone(),
                ModbusOptions::default(),
                Arc::new(profile.clone()),
                &axes,
            )
            .await
            .err()
            .expect("refused");
            let m = e.to_string();
            assert!(
                matches!(e, DriverError::Unsupported { .. })
                    && m.contains("max_feed_mm_min")
                    && m.contains("unit 1"),
                "{feed}: {m}"
            );
        }
    }
}
