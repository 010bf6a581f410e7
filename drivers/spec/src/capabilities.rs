//! What a controller can do beyond moving its axes to a point, so that a job can ask
//! before it plans (stream a rewritten program, upload a compensation table, probe, turn
//! a rotary axis) instead of finding out from an error half-way through.

use crate::axis::Axis;
use serde::Serialize;

#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Capabilities {
    /// Runs a G-code program streamed line by line, so a rewritten program can be run
    /// through the gateway (GRBL: yes; positioning drives: no, they take one target at
    /// a time).
    pub program_streaming: bool,
    /// Keeps a compensation table of its own that the gateway can write (pitch-error or
    /// cross-compensation tables); when false, compensation is done by the gateway.
    pub table_upload: bool,
    /// Probing moves that stop on a touch and report where (G38.2 to G38.5).
    pub probing: bool,
    /// The rotary axes it drives (degrees), in axis order.
    pub rotary_axes: Vec<Axis>,
    /// Reached only through a tape port (DNC drip-feed): it takes programs, and says
    /// nothing back but flow control, alarm and reset: no position, no status, no end
    /// of motion; homing and cycle start are the operator's, on its panel.
    pub tape_only: bool,
}

impl Capabilities {
    /// The rotary axes among `axes`.
    pub fn rotary_among(axes: impl IntoIterator<Item = Axis>) -> Vec<Axis> {
        let mut v: Vec<Axis> = axes.into_iter().filter(|a| a.is_rotary()).collect();
        v.sort();
        v.dedup();
        v
    }
}
