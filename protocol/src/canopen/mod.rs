//! CANopen CiA 301, sans-IO: NMT and heartbeat ([`nmt`]), emergency messages
//! ([`emcy`]), SDO client and server ([`sdo`]), PDO communication and mapping records
//! ([`pdo`]), and the object dictionary with its EDS file parser ([`od`]).
//!
//! Every state machine here takes the time as an argument (`now`, seconds from any
//! origin) and returns the frames to send; none reads a clock or touches a bus.
//!
//! The predefined connection set (CiA 301 7.3.3) gives every node its COB-IDs from its
//! node id (1..=127): see [`Function`].

pub mod emcy;
pub mod nmt;
pub mod od;
pub mod pdo;
pub mod sdo;

use crate::can::CanFrame;

pub const COB_NMT: u16 = 0x000;
pub const COB_SYNC: u16 = 0x080;
pub const COB_EMCY: u16 = 0x080;
pub const COB_TPDO: [u16; 4] = [0x180, 0x280, 0x380, 0x480];
pub const COB_RPDO: [u16; 4] = [0x200, 0x300, 0x400, 0x500];
pub const COB_SDO_TX: u16 = 0x580;
pub const COB_SDO_RX: u16 = 0x600;
pub const COB_HEARTBEAT: u16 = 0x700;

/// A node id, 1..=127.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct NodeId(u8);

impl NodeId {
    pub fn new(id: u8) -> Option<Self> {
        (1..=127).contains(&id).then_some(NodeId(id))
    }

    pub fn get(self) -> u8 {
        self.0
    }

    fn add(self, base: u16) -> u16 {
        base + u16::from(self.0)
    }

    /// Server -> client SDO COB-ID (0x580 + id).
    pub fn sdo_tx(self) -> u16 {
        self.add(COB_SDO_TX)
    }

    /// Client -> server SDO COB-ID (0x600 + id).
    pub fn sdo_rx(self) -> u16 {
        self.add(COB_SDO_RX)
    }

    pub fn emcy(self) -> u16 {
        self.add(COB_EMCY)
    }

    pub fn heartbeat(self) -> u16 {
        self.add(COB_HEARTBEAT)
    }

    /// Default COB-ID of TPDO `n` (1..=4).
    pub fn tpdo(self, n: usize) -> u16 {
        self.add(COB_TPDO[n - 1])
    }

    /// Default COB-ID of RPDO `n` (1..=4).
    pub fn rpdo(self, n: usize) -> u16 {
        self.add(COB_RPDO[n - 1])
    }
}

impl std::fmt::Display for NodeId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "node {}", self.0)
    }
}

/// What a standard COB-ID is in the predefined connection set.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Function {
    Nmt,
    Sync,
    Emcy(NodeId),
    /// TPDO n (1..=4) of a node (node -> master).
    Tpdo(usize, NodeId),
    /// RPDO n (1..=4) of a node (master -> node).
    Rpdo(usize, NodeId),
    SdoTx(NodeId),
    SdoRx(NodeId),
    Heartbeat(NodeId),
    Other(u16),
}

/// Classify a standard COB-ID by the predefined connection set.
pub fn classify(cob_id: u16) -> Function {
    let node = NodeId::new((cob_id & 0x7F) as u8);
    let base = cob_id & 0x780;
    match (cob_id, base, node) {
        (0x000, _, _) => Function::Nmt,
        (0x080, _, _) => Function::Sync,
        (_, 0x080, Some(n)) => Function::Emcy(n),
        (_, 0x180 | 0x280 | 0x380 | 0x480, Some(n)) => {
            Function::Tpdo(usize::from((base - 0x180) / 0x100 + 1), n)
        }
        (_, 0x200 | 0x300 | 0x400 | 0x500, Some(n)) => {
            Function::Rpdo(usize::from((base - 0x200) / 0x100 + 1), n)
        }
        (_, 0x580, Some(n)) => Function::SdoTx(n),
        (_, 0x600, Some(n)) => Function::SdoRx(n),
        (_, 0x700, Some(n)) => Function::Heartbeat(n),
        _ => Function::Other(cob_id),
    }
}

/// A SYNC frame (no counter).
pub fn sync_frame() -> CanFrame {
    CanFrame::std(COB_SYNC, &[])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn predefined_connection_set() {
        let n = NodeId::new(5).unwrap();
        assert_eq!(classify(0x000), Function::Nmt);
        assert_eq!(classify(0x080), Function::Sync);
        assert_eq!(classify(0x085), Function::Emcy(n));
        assert_eq!(classify(0x185), Function::Tpdo(1, n));
        assert_eq!(classify(0x485), Function::Tpdo(4, n));
        assert_eq!(classify(0x205), Function::Rpdo(1, n));
        assert_eq!(classify(0x505), Function::Rpdo(4, n));
        assert_eq!(classify(0x585), Function::SdoTx(n));
        assert_eq!(classify(0x605), Function::SdoRx(n));
        assert_eq!(classify(0x705), Function::Heartbeat(n));
        assert_eq!(classify(0x700), Function::Other(0x700));
        assert_eq!(n.tpdo(2), 0x285);
        assert_eq!(n.rpdo(3), 0x405);
        assert!(NodeId::new(0).is_none() && NodeId::new(128).is_none());
    }
}
