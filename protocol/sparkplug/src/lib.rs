//! Sparkplug B 3.0 (Eclipse Sparkplug), sans-IO: what an edge node puts on MQTT.
//!
//! - [`payload`]: the protobuf payload, field for field as the specification's
//!   `sparkplug_b.proto` (package `org.eclipse.tahu.protobuf`), encoded and decoded with
//!   `prost`; the metric data type codes.
//! - [`topic`]: `spBv1.0/{group_id}/{message_type}/{edge_node_id}[/{device_id}]`, built
//!   and parsed, ids checked (no `+`, `#`, `/`, not empty).
//! - [`EdgeSequence`]: `seq` (0..255, 0 in every NBIRTH, one more in each message after
//!   it, NDEATH excepted) and `bdSeq` (0..255, one more at every MQTT CONNECT, the same
//!   value in the CONNECT's NDEATH will and in the NBIRTH that follows).
//!
//! Worked example: edge node `box-1` of group `plant-a`, device `mill-3`. The node
//! connects with bdSeq 4 (its will: NDEATH on `spBv1.0/plant-a/NDEATH/box-1` carrying
//! metric `bdSeq` = 4, UInt64), publishes NBIRTH (seq 0, metrics `bdSeq` = 4 and
//! `Node Control/Rebirth` = false), DBIRTH on `spBv1.0/plant-a/DBIRTH/box-1/mill-3`
//! (seq 1), then DDATA (seq 2, 3, ..., 255, 0, 1, ...). An NCMD on
//! `spBv1.0/plant-a/NCMD/box-1` with `Node Control/Rebirth` = true makes it publish NBIRTH
//! (seq 0 again, same bdSeq) and every DBIRTH again; a reconnect uses bdSeq 5.

pub mod payload;
pub mod topic;

pub use payload::{DataType, Metric, MetricValue, Payload};
pub use topic::{MessageType, Topic, TopicError};

/// The metric a host application sets to true in an NCMD to ask for a rebirth.
pub const REBIRTH: &str = "Node Control/Rebirth";
/// The birth/death sequence metric of NBIRTH and NDEATH.
pub const BDSEQ: &str = "bdSeq";

/// The edge node's sequence numbers.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct EdgeSequence {
    seq: u8,
}

impl EdgeSequence {
    /// The `seq` of an NBIRTH: 0, and the next message gets 1.
    pub fn birth(&mut self) -> u64 {
        self.seq = 1;
        0
    }

    /// The `seq` of the next DBIRTH, DDATA, NDATA or DDEATH (255 is followed by 0).
    pub fn next_seq(&mut self) -> u64 {
        let s = self.seq;
        self.seq = self.seq.wrapping_add(1);
        u64::from(s)
    }
}

/// The bdSeq after `previous` (None: the first connection ever, 0); 255 wraps to 0.
pub fn next_bdseq(previous: Option<u8>) -> u8 {
    previous.map_or(0, |p| p.wrapping_add(1))
}

/// Whether an NCMD payload asks for a rebirth (`Node Control/Rebirth` = true).
pub fn asks_rebirth(payload: &Payload) -> bool {
    payload.metrics.iter().any(|m| {
        m.name.as_deref() == Some(REBIRTH)
            && matches!(m.value, Some(MetricValue::BooleanValue(true)))
    })
}

#[cfg(test)]
mod tests;
