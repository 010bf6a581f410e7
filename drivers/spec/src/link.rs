//! Which driver opens a device, and with what: one enum per device kind, one variant per
//! link family. `drivers::open_stage` / `drivers::open_camera` are the factory that
//! turns these into open devices; nothing else matches on a link family.

use crate::can::BusSpec;
use crate::canopen::{AxisConfig, CanopenOptions};
use crate::dnc::{DncAxis, DncOptions};
use crate::gige::GigeOptions;
use crate::grbl::GrblOptions;
use crate::linuxcnc::{LinuxcncAxis, LinuxcncOptions};
use crate::modbus::{Endpoint, ModbusAxisConfig, ModbusOptions};
use protocol::modbus::DriveProfile;
use std::fmt;
use std::sync::Arc;
use std::time::Duration;

/// How to reach a motion controller or its drives.
#[derive(Clone, Debug)]
pub enum StageLink {
    /// A GRBL 1.1 controller on a serial port.
    Grbl {
        port: String,
        baud: u32,
        options: GrblOptions,
    },
    /// Positioning drives on Modbus TCP or RTU, one unit per axis, described by a
    /// vendor drive profile.
    Modbus {
        endpoint: Endpoint,
        options: ModbusOptions,
        profile: Arc<DriveProfile>,
        axes: Vec<ModbusAxisConfig>,
    },
    /// CiA 402 drives on a CAN bus, one node per axis.
    Canopen {
        bus: BusSpec,
        options: CanopenOptions,
        axes: Vec<AxisConfig>,
    },
    /// A LinuxCNC machine through its text remote shell `linuxcncrsh` (TCP, default
    /// port 5007): `address` is `host:port`.
    Linuxcnc {
        address: String,
        options: LinuxcncOptions,
        axes: Vec<LinuxcncAxis>,
    },
    /// A closed controller's tape port (DNC drip-feed, DC1/DC3) on a serial port: it
    /// takes programs and says nothing back but flow control, alarm and reset.
    Dnc {
        port: String,
        baud: u32,
        options: DncOptions,
        axes: Vec<DncAxis>,
    },
}

impl fmt::Display for StageLink {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            StageLink::Grbl { port, baud, .. } => write!(f, "GRBL at {port} @{baud}"),
            StageLink::Modbus { endpoint, .. } => write!(f, "{endpoint}"),
            StageLink::Canopen { bus, .. } => write!(f, "CANopen on {bus}"),
            StageLink::Linuxcnc { address, .. } => write!(f, "LinuxCNC at {address}"),
            StageLink::Dnc { port, baud, .. } => write!(f, "tape port (DNC) at {port} @{baud}"),
        }
    }
}

/// How to reach a camera.
#[derive(Clone, Debug, PartialEq)]
pub enum CameraLink {
    /// GigE Vision through the pure-Rust driver: `device` is an address (`192.168.1.20`,
    /// `127.0.0.1:3956`) or a name to discover (vendor, model, serial or user name).
    Gige {
        device: String,
        options: GigeOptions,
    },
    /// GigE Vision or USB3 Vision through the Aravis library (the `aravis` build
    /// feature): `name` as Aravis lists it, or the first camera found.
    Aravis {
        name: Option<String>,
        frame_timeout: Duration,
    },
}

impl fmt::Display for CameraLink {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CameraLink::Gige { device, .. } => write!(f, "GigE Vision camera {device}"),
            CameraLink::Aravis { name: Some(n), .. } => write!(f, "Aravis camera {n}"),
            CameraLink::Aravis { name: None, .. } => write!(f, "the first Aravis camera"),
        }
    }
}
