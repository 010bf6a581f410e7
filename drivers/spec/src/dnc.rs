//! A closed controller reached through its tape port (DNC drip-feed): how the sender
//! talks to it. Every detail the public manuals leave open is an option here, with its
//! default stated (docs/dnc.md has the controller families' settings).

use crate::axis::Axis;
use std::time::Duration;

/// End of block as the sender writes it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EndOfBlock {
    /// LF: Fanuc's ISO end of block (default).
    Lf,
    /// CR LF: Haas setting 25, Siemens' CR LF bit.
    CrLf,
}

/// How the drip-feed sender behaves.
#[derive(Clone, Debug, PartialEq)]
pub struct DncOptions {
    /// Wait for the controller's DC1 before the first character of a tape (the control
    /// sends it when the operator presses cycle start in DNC/remote mode). Default on;
    /// off for a control that reads without asking (then it starts at once).
    pub wait_for_dc1: bool,
    /// How long the operator has to press cycle start (the first DC1). Default 600 s.
    pub start_timeout: Duration,
    /// How long a DC3 may last before the sender gives up (the control stops reading
    /// while its buffer is full: a long dwell or a feed hold lasts that long). Default
    /// 600 s.
    pub resume_timeout: Duration,
    /// Characters written at once before the sender looks for DC3 again; at most the
    /// control's overrun allowance (Fanuc reader port: 10 after DC3). Default 8.
    pub chunk: usize,
    /// End of block. Default LF.
    pub end_of_block: EndOfBlock,
    /// NULs sent before the tape (a leader; Heidenhain's standard protocol sends 50).
    /// Default 0.
    pub leader_nuls: usize,
}

impl Default for DncOptions {
    fn default() -> Self {
        Self {
            wait_for_dc1: true,
            start_timeout: Duration::from_secs(600),
            resume_timeout: Duration::from_secs(600),
            chunk: 8,
            end_of_block: EndOfBlock::Lf,
            leader_nuls: 0,
        }
    }
}

/// An axis of the machine behind the tape port: the job file states its travel (the
/// control does not tell it).
#[derive(Clone, Debug, PartialEq)]
pub struct DncAxis {
    pub axis: Axis,
    pub min_mm: f64,
    pub max_mm: f64,
    pub max_feed_mm_min: f64,
}
