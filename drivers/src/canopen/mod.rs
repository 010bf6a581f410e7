//! CANopen CiA 402 drives: [`network`] is the master's side of one bus (frame routing
//! by COB-ID, one SDO client per node, TPDO decoding, EMCY, heartbeat supervision),
//! [`axis`] is one drive as an [`AxisDrive`](crate::AxisDrive), and [`open_stage`]
//! makes several drives (node ids) on one bus into the [`Stage`](crate::Stage) the
//! pipeline uses.

pub mod axis;
pub mod network;

pub use axis::{AxisConfig, CanopenOptions, Cia402Axis};
pub use network::{NetStats, Network, NodeView};

use crate::can::CanBus;
use crate::error::DriverError;
use crate::multi_axis::{AxisDrive, MultiAxisStage};

/// Bring up every axis's node on `bus` and make them one stage. The network handle is
/// returned too (statistics, EMCY history, heartbeat state).
pub async fn open_stage(
    bus: Box<dyn CanBus>,
    axes: Vec<AxisConfig>,
    opts: CanopenOptions,
) -> Result<(MultiAxisStage, Network), DriverError> {
    for a in &axes {
        crate::stage::check_axis_config(
            &format!("CANopen node {}", a.node),
            &format!("axis {}", a.axis),
            a.min_mm,
            a.max_mm,
            Some(a.max_feed_mm_min),
        )?;
    }
    let net = Network::start(bus, opts.sdo_timeout);
    let mut drives: Vec<Box<dyn AxisDrive>> = Vec::new();
    let mut names = Vec::new();
    for a in axes {
        names.push(format!("{} = node {}", a.axis, a.node));
        drives.push(Box::new(Cia402Axis::connect(&net, a, opts.clone()).await?));
    }
    let name = format!("CANopen CiA 402 on {}: {}", net.name(), names.join(", "));
    Ok((MultiAxisStage::new(&name, drives)?, net))
}
