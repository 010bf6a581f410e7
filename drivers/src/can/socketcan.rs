//! A CAN bus on a Linux SocketCAN interface (`can0`, `vcan0`) through the `socketcan`
//! crate's tokio socket. The interface must exist and be up (`ip link set can0 up type
//! can bitrate 1000000`); the bitrate is the interface's business, not the socket's.
//!
//! On a machine whose kernel has no CAN support, or without the interface, opening
//! fails with [`DriverError::NotAvailable`] and the reason, so callers (and tests) can
//! tell "not here" from "broken".

use super::{BusStats, CanBus};
use crate::error::DriverError;
use async_trait::async_trait;
use protocol::can::{CanFrame, CanId};
use socketcan::{EmbeddedFrame, ExtendedId, Id, Socket, StandardId};

pub struct SocketCanBus {
    socket: socketcan::tokio::CanSocket,
    name: String,
    stats: BusStats,
}

/// Why SocketCAN cannot be used here, or `None` if `interface` opens.
pub fn unavailable(interface: &str) -> Option<String> {
    match socketcan::CanSocket::open(interface) {
        Ok(_) => None,
        Err(e) => Some(explain(interface, &e)),
    }
}

fn explain(interface: &str, e: &std::io::Error) -> String {
    // The interface name is looked up before the socket is made, so "no such device"
    // may hide a kernel without CAN at all: ask for an AF_CAN socket bound to any
    // interface (index 0) to tell them apart.
    let no_af_can = |e: &std::io::Error| e.raw_os_error() == Some(97);
    if no_af_can(e) {
        return format!("the kernel has no CAN support (socket(AF_CAN) failed: {e})");
    }
    if let Err(probe) = socketcan::CanSocket::open_iface(0) {
        if no_af_can(&probe) {
            return format!("the kernel has no CAN support (socket(AF_CAN) failed: {probe})");
        }
    }
    match e.raw_os_error() {
        Some(19) => format!("there is no CAN interface `{interface}` ({e})"),
        _ => format!("cannot open CAN interface `{interface}`: {e}"),
    }
}

impl SocketCanBus {
    pub fn open(interface: &str) -> Result<Self, DriverError> {
        let socket = socketcan::tokio::CanSocket::open(interface).map_err(|e| {
            DriverError::NotAvailable {
                backend: format!("socketcan {interface}"),
                reason: explain(interface, &e),
            }
        })?;
        Ok(Self {
            socket,
            name: format!("socketcan {interface}"),
            stats: BusStats::default(),
        })
    }

    fn transport(&self, message: String) -> DriverError {
        DriverError::Transport {
            device: self.name.clone(),
            message,
        }
    }
}

fn to_socketcan(f: &CanFrame) -> Option<socketcan::CanFrame> {
    let id: Id = match f.id() {
        CanId::Standard(i) => StandardId::new(i)?.into(),
        CanId::Extended(i) => ExtendedId::new(i)?.into(),
    };
    if f.is_remote() {
        socketcan::CanFrame::new_remote(id, usize::from(f.dlc()))
    } else {
        socketcan::CanFrame::new(id, f.data())
    }
}

fn from_socketcan(f: &socketcan::CanFrame) -> Option<CanFrame> {
    let id = match f.id() {
        Id::Standard(i) => CanId::Standard(i.as_raw()),
        Id::Extended(i) => CanId::Extended(i.as_raw()),
    };
    match f {
        socketcan::CanFrame::Data(_) => CanFrame::new(id, f.data()).ok(),
        socketcan::CanFrame::Remote(_) => CanFrame::remote(id, f.dlc() as u8).ok(),
        socketcan::CanFrame::Error(_) => None,
    }
}

#[async_trait]
impl CanBus for SocketCanBus {
    fn name(&self) -> &str {
        &self.name
    }

    async fn send(&mut self, frame: &CanFrame) -> Result<(), DriverError> {
        let f = to_socketcan(frame)
            .ok_or_else(|| self.transport(format!("frame {frame} cannot be built")))?;
        self.socket
            .write_frame(f)
            .await
            .map_err(|e| self.transport(format!("write failed: {e}")))?;
        self.stats.frames_sent += 1;
        Ok(())
    }

    async fn recv(&mut self) -> Result<CanFrame, DriverError> {
        loop {
            let f = self
                .socket
                .read_frame()
                .await
                .map_err(|e| self.transport(format!("read failed: {e}")))?;
            match from_socketcan(&f) {
                Some(f) => {
                    self.stats.frames_received += 1;
                    return Ok(f);
                }
                // Error frames (bus-off, error passive...) are counted, not delivered.
                None => self.stats.adapter_errors += 1,
            }
        }
    }

    fn stats(&self) -> BusStats {
        self.stats.clone()
    }
}
