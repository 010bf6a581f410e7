//! Running a whole G-code program streamed line by line (the `program_streaming`
//! capability): how to stream, what a finished stream reports, and where a stopped one
//! stopped. The GRBL driver streams by character counting (`grbl/stream.rs`); any
//! controller that runs streamed programs answers in these terms through
//! [`Stage::stream_program`](crate::Stage::stream_program).

use crate::error::DriverError;
use protocol::grbl::stream::StreamProgress;
use std::fmt;
use std::time::Duration;

/// How to stream.
#[derive(Clone, Debug)]
pub struct StreamOptions {
    /// Run every line through the protocol's G-code interpreter (seeded with the
    /// controller's `$G` state) before sending anything: a malformed line is reported
    /// with the error GRBL would give, and nothing moves.
    pub preflight: bool,
    /// Poll `?` this often while streaming (progress of execution, `Bf:`).
    pub status_interval: Duration,
    /// Wait for the motion to end after the last `ok` (then every line is executed).
    pub wait_until_executed: bool,
    /// Skip this many leading lines (to resume explicitly after a failure).
    pub start_line: usize,
}

impl Default for StreamOptions {
    fn default() -> Self {
        Self {
            preflight: true,
            status_interval: Duration::from_millis(200),
            wait_until_executed: true,
            start_line: 0,
        }
    }
}

/// A finished stream.
#[derive(Clone, Debug, PartialEq)]
pub struct StreamReport {
    pub progress: StreamProgress,
    /// Most bytes unacknowledged at once (never above the RX budget).
    pub max_in_flight_bytes: usize,
    /// RX buffer size the character count used.
    pub rx_buffer: usize,
    /// Fewest free planner blocks seen in a status report (0: the planner was full).
    pub min_free_blocks: Option<u16>,
    pub elapsed: Duration,
}

/// A stream that stopped. `progress.acknowledged` lines (1..=n) were answered; lines
/// `acknowledged+1..=sent` were written but not answered; nothing after `sent` was
/// written. Nothing is ever resent.
#[derive(Debug)]
pub struct StreamError {
    pub cause: DriverError,
    /// 1-based number of the program line that failed, when one did.
    pub line: Option<usize>,
    /// Its text as sent (filtered).
    pub text: Option<String>,
    pub progress: StreamProgress,
    /// Lines after the failed one that GRBL had already buffered and acknowledged
    /// (character counting keeps up to 127 bytes ahead; GRBL ran them).
    pub acknowledged_after: Vec<usize>,
}

impl fmt::Display for StreamError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if let Some(l) = self.line {
            write!(f, "line {l}")?;
            if let Some(t) = &self.text {
                write!(f, " `{t}`")?;
            }
            write!(f, ": ")?;
        }
        write!(f, "{}; ", self.cause)?;
        let p = &self.progress;
        if p.acknowledged > 0 {
            write!(f, "lines 1..={} acknowledged", p.acknowledged)?;
        } else {
            write!(f, "no line acknowledged")?;
        }
        if p.sent > p.acknowledged {
            write!(
                f,
                ", lines {}..={} sent but not acknowledged (they may or may not have run)",
                p.acknowledged + 1,
                p.sent
            )?;
        }
        if !self.acknowledged_after.is_empty() {
            let first = self.acknowledged_after[0];
            let last = self.acknowledged_after[self.acknowledged_after.len() - 1];
            write!(
                f,
                ", lines {first}..={last} after it were already buffered and executed"
            )?;
        }
        write!(f, "; nothing after line {} was sent", p.sent)
    }
}

impl std::error::Error for StreamError {}

impl From<StreamError> for DriverError {
    fn from(e: StreamError) -> Self {
        e.cause
    }
}
