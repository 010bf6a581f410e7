//! Character-counting streaming, sans-IO.
//!
//! GRBL acknowledges every line with exactly one `ok` or `error:N`, in order, and holds
//! at most `RX_BUFFER_SIZE` (128) bytes of unprocessed input. A host that keeps the total
//! length of its unacknowledged lines within that budget keeps the RX buffer full (so
//! the planner never starves) without ever overflowing it: GRBL silently drops bytes
//! that arrive to a full buffer, which would corrupt a line. This is the protocol's
//! recommended streaming method; [`CharCounter`] is its bookkeeping and
//! [`ProgramStream`] applies it to a whole program with progress and stop-on-error.

use super::gcode::{filter_line, FilterError};
use super::response::Response;
use std::collections::VecDeque;

/// GRBL's RX buffer size when the device does not tell (`[OPT:..,..,rx]` or `Bf:`).
pub const DEFAULT_RX_BUFFER: usize = 128;

/// Bookkeeping of the bytes in flight. Line ids are the caller's (e.g. program indices).
#[derive(Clone, Debug)]
pub struct CharCounter {
    rx_size: usize,
    in_flight: VecDeque<(usize, usize)>,
    used: usize,
}

impl CharCounter {
    /// A counter for a device with an RX buffer of `rx_size` bytes. One byte is kept
    /// free, as GRBL's reference streamer does.
    pub fn new(rx_size: usize) -> Self {
        Self {
            rx_size: rx_size.max(2),
            in_flight: VecDeque::new(),
            used: 0,
        }
    }

    /// Bytes that may be unacknowledged at once.
    pub fn budget(&self) -> usize {
        self.rx_size - 1
    }

    pub fn rx_size(&self) -> usize {
        self.rx_size
    }

    pub fn used(&self) -> usize {
        self.used
    }

    pub fn in_flight(&self) -> usize {
        self.in_flight.len()
    }

    /// Whether a line of `len` bytes (line ending included) may be sent now.
    pub fn fits(&self, len: usize) -> bool {
        self.used + len <= self.budget()
    }

    /// Whether a line of `len` bytes could ever be sent (with nothing in flight).
    pub fn can_ever_fit(&self, len: usize) -> bool {
        len <= self.budget()
    }

    /// Record a line as sent. Returns false (and records nothing) if it does not fit.
    pub fn push(&mut self, id: usize, len: usize) -> bool {
        if !self.fits(len) {
            return false;
        }
        self.in_flight.push_back((id, len));
        self.used += len;
        true
    }

    /// An `ok`/`error` arrived: retire the oldest line, returning its id.
    pub fn retire(&mut self) -> Option<usize> {
        let (id, len) = self.in_flight.pop_front()?;
        self.used -= len;
        Some(id)
    }

    /// GRBL reset (banner seen): its RX buffer was flushed, nothing in flight will be
    /// answered. Returns the ids that were lost, oldest first.
    pub fn reset(&mut self) -> Vec<usize> {
        self.used = 0;
        self.in_flight.drain(..).map(|(id, _)| id).collect()
    }

    /// A device told its RX buffer size (`[OPT:]`) or showed this many free bytes
    /// (`Bf:`): a free count can only be a lower bound of the size, so the budget
    /// only ever grows from it (grblHAL has 1024 bytes).
    pub fn observe_rx_size(&mut self, bytes: usize) {
        if bytes > self.rx_size {
            self.rx_size = bytes;
        }
    }
}

/// Where a streamed program stands.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StreamProgress {
    /// Lines in the program.
    pub total: usize,
    /// Lines written to the device.
    pub sent: usize,
    /// Lines the device answered (`ok` or `error`), always a prefix of the program.
    pub acknowledged: usize,
    /// Lines known to have finished executing (a lower bound; see the driver).
    pub executed: usize,
}

/// What a response meant for the stream.
#[derive(Clone, Debug, PartialEq)]
pub enum StreamEvent {
    /// Line (0-based index) acknowledged with `ok`.
    Acknowledged(usize),
    /// Line refused with `error:N`; the stream stops sending.
    Refused { index: usize, code: u8 },
    /// GRBL reset: these lines were in flight and are lost (never answered).
    Lost(Vec<usize>),
    /// Not a line response.
    None,
}

/// Why a program cannot be streamed as written (found before anything is sent).
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("line {line}: {error}")]
pub struct ProgramError {
    /// 1-based line number in the program text.
    pub line: usize,
    pub error: FilterError,
}

/// A program being streamed by character counting. Lines are sent as GRBL will see
/// them after its own filtering (comments and whitespace removed), so a comment can
/// never smuggle a real-time byte (`!`, `?`, `~`) into the stream, and fewer bytes go
/// over the line.
#[derive(Clone, Debug)]
pub struct ProgramStream {
    lines: Vec<String>,
    next: usize,
    counter: CharCounter,
    acknowledged: usize,
    executed: usize,
    refused: Option<(usize, u8)>,
}

impl ProgramStream {
    /// Prepare a program: every line is filtered as GRBL does; a line GRBL would
    /// reject for its length, or one holding a real-time byte, is refused here with
    /// its 1-based number.
    pub fn new(program: &str, rx_size: usize) -> Result<Self, ProgramError> {
        let mut lines = Vec::new();
        for (i, raw) in program.lines().enumerate() {
            let l = filter_line(raw).map_err(|error| ProgramError { line: i + 1, error })?;
            lines.push(l);
        }
        Ok(Self {
            lines,
            next: 0,
            counter: CharCounter::new(rx_size),
            acknowledged: 0,
            executed: 0,
            refused: None,
        })
    }

    pub fn lines(&self) -> &[String] {
        &self.lines
    }

    pub fn counter(&self) -> &CharCounter {
        &self.counter
    }

    pub fn counter_mut(&mut self) -> &mut CharCounter {
        &mut self.counter
    }

    /// The next line to send (index, bytes with `\n`) if one is due and fits in the
    /// budget; it is recorded as sent. Nothing is sent after a refusal.
    pub fn next_to_send(&mut self) -> Option<(usize, Vec<u8>)> {
        if self.refused.is_some() || self.next >= self.lines.len() {
            return None;
        }
        let mut bytes = self.lines[self.next].clone().into_bytes();
        bytes.push(b'\n');
        if !self.counter.push(self.next, bytes.len()) {
            return None;
        }
        self.next += 1;
        Some((self.next - 1, bytes))
    }

    /// Apply a response from the device.
    pub fn on_response(&mut self, r: &Response) -> StreamEvent {
        match r {
            Response::Ok | Response::Error(_) => {
                let Some(index) = self.counter.retire() else {
                    return StreamEvent::None;
                };
                self.acknowledged = index + 1;
                match r {
                    Response::Error(code) => {
                        if self.refused.is_none() {
                            self.refused = Some((index, *code));
                        }
                        StreamEvent::Refused { index, code: *code }
                    }
                    _ => StreamEvent::Acknowledged(index),
                }
            }
            Response::Banner { .. } => StreamEvent::Lost(self.counter.reset()),
            _ => StreamEvent::None,
        }
    }

    /// Record that the first `n` lines have finished executing.
    pub fn set_executed(&mut self, n: usize) {
        self.executed = self.executed.max(n.min(self.acknowledged));
    }

    /// The first refusal: (0-based line index, GRBL error code).
    pub fn refused(&self) -> Option<(usize, u8)> {
        self.refused
    }

    /// All lines sent and answered, or stopped on a refusal with nothing in flight.
    pub fn is_finished(&self) -> bool {
        self.counter.in_flight() == 0 && (self.next >= self.lines.len() || self.refused.is_some())
    }

    pub fn progress(&self) -> StreamProgress {
        StreamProgress {
            total: self.lines.len(),
            sent: self.next,
            acknowledged: self.acknowledged,
            executed: self.executed,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counter_keeps_within_budget_and_retires_in_order() {
        let mut c = CharCounter::new(128);
        assert_eq!(c.budget(), 127);
        assert!(c.push(0, 100));
        assert!(!c.push(1, 28));
        assert!(c.push(1, 27));
        assert_eq!(c.used(), 127);
        assert_eq!(c.retire(), Some(0));
        assert!(c.push(2, 100));
        assert_eq!(c.reset(), vec![1, 2]);
        assert_eq!(c.used(), 0);
        c.observe_rx_size(100);
        assert_eq!(c.rx_size(), 128);
        c.observe_rx_size(1024);
        assert_eq!(c.budget(), 1023);
    }

    #[test]
    fn program_streams_filtered_lines_and_stops_on_error() {
        let prog = "G21 (mm)\nG1 X1 F100 ; go\n\nG1 X2\nG1 X3\n";
        let mut s = ProgramStream::new(prog, 20).unwrap();
        assert_eq!(s.lines(), ["G21", "G1X1F100", "", "G1X2", "G1X3"]);
        let mut sent = Vec::new();
        while let Some((i, b)) = s.next_to_send() {
            sent.push((i, b));
        }
        // 4 + 9 + 1 + 5 = 19 bytes fit the 19-byte budget; "G1X3\n" waits.
        assert_eq!(sent.len(), 4);
        assert_eq!(sent[1].1, b"G1X1F100\n");
        assert_eq!(s.on_response(&Response::Ok), StreamEvent::Acknowledged(0));
        assert_eq!(
            s.on_response(&Response::Error(22)),
            StreamEvent::Refused { index: 1, code: 22 }
        );
        assert_eq!(s.next_to_send(), None, "nothing is sent after a refusal");
        assert!(!s.is_finished());
        s.on_response(&Response::Ok);
        s.on_response(&Response::Ok);
        assert!(s.is_finished());
        assert_eq!(s.refused(), Some((1, 22)));
        assert_eq!(
            s.progress(),
            StreamProgress {
                total: 5,
                sent: 4,
                acknowledged: 4,
                executed: 0
            }
        );
    }

    #[test]
    fn realtime_bytes_and_long_lines_are_refused_before_sending() {
        let e = ProgramStream::new("G0X1\nG1X2!\n", 128).unwrap_err();
        assert_eq!(e.line, 2);
        let long = format!("G1X1{}\n", "0".repeat(90));
        let e = ProgramStream::new(&long, 128).unwrap_err();
        assert_eq!(e.line, 1);
        assert!(e.to_string().contains("79"), "{e}");
    }

    #[test]
    fn banner_loses_lines_in_flight() {
        let mut s = ProgramStream::new("G0X1\nG0X2\n", 128).unwrap();
        s.next_to_send();
        s.next_to_send();
        s.on_response(&Response::Ok);
        let ev = s.on_response(&Response::Banner {
            firmware: "Grbl".into(),
            version: "1.1h".into(),
        });
        assert_eq!(ev, StreamEvent::Lost(vec![1]));
    }
}
