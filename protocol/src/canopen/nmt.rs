//! Network management (NMT) commands, node states, boot-up and heartbeat messages, and
//! a heartbeat consumer that tells when a producer has gone quiet.

use super::{NodeId, COB_HEARTBEAT, COB_NMT};
use crate::can::CanFrame;

/// NMT commands (byte 0 of a COB-ID 0 frame; byte 1 is the node id, 0 = all nodes).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NmtCommand {
    Start = 0x01,
    Stop = 0x02,
    EnterPreOperational = 0x80,
    ResetNode = 0x81,
    ResetCommunication = 0x82,
}

impl NmtCommand {
    pub fn from_byte(b: u8) -> Option<Self> {
        Some(match b {
            0x01 => Self::Start,
            0x02 => Self::Stop,
            0x80 => Self::EnterPreOperational,
            0x81 => Self::ResetNode,
            0x82 => Self::ResetCommunication,
            _ => return None,
        })
    }

    /// The command frame for one node (`Some`) or all (`None`).
    pub fn frame(self, node: Option<NodeId>) -> CanFrame {
        CanFrame::std(COB_NMT, &[self as u8, node.map_or(0, NodeId::get)])
    }

    /// Parse an NMT frame: the command and the addressed node (0 = all).
    pub fn parse(frame: &CanFrame) -> Option<(NmtCommand, u8)> {
        if frame.id().as_standard() != Some(COB_NMT) || frame.is_remote() {
            return None;
        }
        match frame.data() {
            [c, n] => Some((Self::from_byte(*c)?, *n)),
            _ => None,
        }
    }

    /// Whether this command frame addresses `node`.
    pub fn addresses(target: u8, node: NodeId) -> bool {
        target == 0 || target == node.get()
    }
}

/// NMT states as a heartbeat reports them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NmtState {
    /// Boot-up message (sent once after initialisation).
    BootUp = 0x00,
    Stopped = 0x04,
    Operational = 0x05,
    PreOperational = 0x7F,
}

impl NmtState {
    /// Decode a heartbeat state byte (bit 7 is the node-guarding toggle, ignored).
    pub fn from_byte(b: u8) -> Option<Self> {
        Some(match b & 0x7F {
            0x00 => Self::BootUp,
            0x04 => Self::Stopped,
            0x05 => Self::Operational,
            0x7F => Self::PreOperational,
            _ => return None,
        })
    }

    pub fn name(self) -> &'static str {
        match self {
            Self::BootUp => "boot-up",
            Self::Stopped => "stopped",
            Self::Operational => "operational",
            Self::PreOperational => "pre-operational",
        }
    }
}

/// A heartbeat (or boot-up) frame of `node`.
pub fn heartbeat_frame(node: NodeId, state: NmtState) -> CanFrame {
    CanFrame::std(node.heartbeat(), &[state as u8])
}

/// Parse a heartbeat/boot-up frame.
pub fn parse_heartbeat(frame: &CanFrame) -> Option<(NodeId, NmtState)> {
    let id = frame.id().as_standard()?;
    if id & 0x780 != COB_HEARTBEAT || frame.is_remote() {
        return None;
    }
    let node = NodeId::new((id & 0x7F) as u8)?;
    match frame.data() {
        [b] => Some((node, NmtState::from_byte(*b)?)),
        _ => None,
    }
}

/// What the consumer learnt from [`HeartbeatConsumer::check`].
#[derive(Clone, Debug, PartialEq)]
pub struct HeartbeatLost {
    pub node: NodeId,
    /// Seconds since the last heartbeat (or since watching began, if none came).
    pub silent_for_s: f64,
    pub timeout_s: f64,
}

#[derive(Clone, Debug)]
struct Watched {
    node: NodeId,
    timeout_s: f64,
    since: f64,
    state: Option<NmtState>,
    lost: bool,
}

/// Heartbeat consumer (CiA 301 0x1016 semantics): each watched producer must be heard
/// within its timeout; a lapse is reported once, until the producer is heard again.
#[derive(Clone, Debug, Default)]
pub struct HeartbeatConsumer {
    watched: Vec<Watched>,
}

impl HeartbeatConsumer {
    pub fn new() -> Self {
        Self::default()
    }

    /// Start (or restart) watching `node`; the first lapse counts from `now`.
    pub fn watch(&mut self, node: NodeId, timeout_s: f64, now: f64) {
        self.watched.retain(|w| w.node != node);
        self.watched.push(Watched {
            node,
            timeout_s,
            since: now,
            state: None,
            lost: false,
        });
    }

    pub fn unwatch(&mut self, node: NodeId) {
        self.watched.retain(|w| w.node != node);
    }

    /// Feed any frame; returns the producer's state if it was a watched heartbeat.
    pub fn on_frame(&mut self, frame: &CanFrame, now: f64) -> Option<(NodeId, NmtState)> {
        let (node, state) = parse_heartbeat(frame)?;
        let w = self.watched.iter_mut().find(|w| w.node == node)?;
        w.since = now;
        w.state = Some(state);
        w.lost = false;
        Some((node, state))
    }

    /// Producers whose heartbeat lapsed since the last check (each reported once).
    pub fn check(&mut self, now: f64) -> Vec<HeartbeatLost> {
        let mut out = Vec::new();
        for w in &mut self.watched {
            let silent = now - w.since;
            if !w.lost && silent > w.timeout_s {
                w.lost = true;
                out.push(HeartbeatLost {
                    node: w.node,
                    silent_for_s: silent,
                    timeout_s: w.timeout_s,
                });
            }
        }
        out
    }

    /// Restart every running window at `now` (lapsed producers stay lapsed). For a
    /// consumer that was itself not scheduled for a while: the silence it would see is
    /// its own, not the producers'.
    pub fn restart_windows(&mut self, now: f64) {
        for w in self.watched.iter_mut().filter(|w| !w.lost) {
            w.since = w.since.max(now);
        }
    }

    /// The shortest timeout watched.
    pub fn min_timeout(&self) -> Option<f64> {
        self.watched.iter().map(|w| w.timeout_s).reduce(f64::min)
    }

    /// Whether `node`'s heartbeat is currently lapsed.
    pub fn is_lost(&self, node: NodeId) -> bool {
        self.watched.iter().any(|w| w.node == node && w.lost)
    }

    /// Last state heard from `node`.
    pub fn state(&self, node: NodeId) -> Option<NmtState> {
        self.watched
            .iter()
            .find(|w| w.node == node)
            .and_then(|w| w.state)
    }

    /// The earliest time a lapse could be detected (for a timer), if any is watched.
    pub fn next_deadline(&self) -> Option<f64> {
        self.watched
            .iter()
            .filter(|w| !w.lost)
            .map(|w| w.since + w.timeout_s)
            .reduce(f64::min)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn commands_and_heartbeats_round_trip() {
        let n = NodeId::new(3).unwrap();
        let f = NmtCommand::Start.frame(Some(n));
        assert_eq!(f.to_string(), "000#0103");
        assert_eq!(NmtCommand::parse(&f), Some((NmtCommand::Start, 3)));
        assert_eq!(
            NmtCommand::parse(&NmtCommand::ResetNode.frame(None)),
            Some((NmtCommand::ResetNode, 0))
        );
        assert!(NmtCommand::parse(&CanFrame::std(0, &[0x99, 1])).is_none());
        let hb = heartbeat_frame(n, NmtState::PreOperational);
        assert_eq!(hb.to_string(), "703#7F");
        assert_eq!(parse_heartbeat(&hb), Some((n, NmtState::PreOperational)));
        // The node-guarding toggle bit is ignored.
        assert_eq!(
            parse_heartbeat(&CanFrame::std(0x703, &[0x85])),
            Some((n, NmtState::Operational))
        );
        assert!(parse_heartbeat(&CanFrame::std(0x703, &[0x33])).is_none());
    }

    #[test]
    fn consumer_reports_a_lapse_once_and_recovers() {
        let n = NodeId::new(2).unwrap();
        let mut c = HeartbeatConsumer::new();
        c.watch(n, 0.3, 0.0);
        assert_eq!(c.next_deadline(), Some(0.3));
        assert!(c.check(0.2).is_empty());
        c.on_frame(&heartbeat_frame(n, NmtState::Operational), 0.25);
        assert!(c.check(0.5).is_empty());
        let lost = c.check(0.6);
        assert_eq!(lost.len(), 1);
        assert_eq!(lost[0].node, n);
        assert!(c.is_lost(n));
        assert!(c.check(5.0).is_empty(), "reported once");
        let m = NodeId::new(3).unwrap();
        c.watch(m, 0.3, 5.0);
        c.restart_windows(6.0);
        assert!(c.check(6.2).is_empty(), "window restarted at 6.0");
        assert_eq!(c.min_timeout(), Some(0.3));
        c.on_frame(&heartbeat_frame(n, NmtState::Operational), 5.1);
        assert!(!c.is_lost(n));
        assert_eq!(c.state(n), Some(NmtState::Operational));
    }
}
