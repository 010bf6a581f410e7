//! The pass-through's state machine, sans-IO: bytes from the sender and from the
//! controller in, bytes to each out. The I/O loop ([`crate::serve`]) only moves bytes.
//!
//! Towards the sender it is a GRBL 1.1 controller: every line gets exactly one `ok` or
//! `error:N`, in order; real-time bytes act at once; status reports show the programmed
//! (nominal) position. Towards the controller it is a character-counting sender: pieces
//! go out while they fit in the controller's RX buffer, so its planner stays fed.
//!
//! A sender line becomes one or more pieces (the rewriter splits moves); its `ok` goes
//! back when the controller has acknowledged its last piece; if any piece was refused,
//! the sender gets that piece's `error:N` instead. A line the rewriter refuses is never
//! sent: the sender gets `[MSG:...]` naming the reason and `error:N` (see
//! [`refusal_code`]) in its turn.

use crate::line_rewriter::{CartesianRewriter, LineRewriter};
use protocol::grbl::gcode::LINE_BUFFER_SIZE;
use protocol::grbl::realtime::{classify, Realtime, RxByte};
use protocol::grbl::response::Response;
use protocol::grbl::status::{MachineState, StatusReport};
use rewrite::{Compensation, RewriteError, RewriteErrorKind, Rewriter};
use std::collections::VecDeque;

/// GRBL's serial RX buffer (stock 1.1).
pub const RX_BUFFER: usize = 128;

/// Bytes of a sender line kept as sent (comments and spaces included). Past this the
/// line is kept as GRBL itself keeps it (no spaces, no comments, at most
/// [`LINE_BUFFER_SIZE`] - 1 characters): what a sender can make the gateway hold for
/// one line is bounded whatever it sends.
pub const RAW_LINE_KEPT: usize = 4096;

/// Sender lines received and not yet answered beyond which the gateway stops reading
/// from the sender until the controller catches up (a sender that keeps to GRBL's
/// 128-byte buffer never has more than 64 lines unanswered).
pub const MAX_UNANSWERED_LINES: usize = 1024;

/// One-time status report fields of GRBL 1.1 and grblHAL that are not `WCO:`, `Ov:` or
/// `A:`: grblHAL sends them only when they change (or on a full report).
const ONE_TIME_FIELDS: [&str; 9] = ["WCS", "Sc", "MPG", "H", "D", "T", "P", "TLR", "In"];

/// The `error:N` a sender gets for a line the gateway refused (GRBL has no code of its
/// own for these): 33 "motion command target is invalid" for a target the compensation
/// cannot serve (outside the map or the soft limits, a correction beyond the bound, an
/// unknown position), 20 "unsupported command" for G93, the controller's own code for
/// what it would refuse itself, 1/2 for unreadable words, 11 for an overlong line.
pub fn refusal_code(e: &RewriteError) -> u8 {
    match &e.kind {
        RewriteErrorKind::Refused { code } => *code,
        RewriteErrorKind::Syntax(s) => match s.kind {
            protocol::nc::ErrorKind::ExpectedNumber { .. } => 2,
            _ => 1,
        },
        RewriteErrorKind::Filter(protocol::grbl::gcode::FilterError::Overflow { .. }) => 11,
        RewriteErrorKind::Filter(_) => 1,
        RewriteErrorKind::InverseTime => 20,
        _ => 33,
    }
}

/// One sender line waiting for its answer.
#[derive(Debug)]
struct Slot {
    /// 1-based number of the line as the sender sent it (since the session started).
    line: u64,
    /// Pieces sent or queued and not yet answered by the controller.
    outstanding: usize,
    /// The first `error:N` among its pieces (or the gateway's refusal).
    error: Option<u8>,
    /// Seconds (caller's clock) when the line arrived, for the latency figure.
    received_s: f64,
    /// When its first piece went to the controller.
    first_sent_s: Option<f64>,
    /// The line is a homing (`$H`): its `ok` means the machine's zero moved.
    homing: bool,
}

/// The `error:N` a motion line gets while the map's reference is stale after a homing
/// and none could be measured: 9, GRBL's "G-code locked out during alarm or jog state"
/// (the motion is locked out until the zero is known again; `$` commands still pass).
pub const UNREFERENCED_CODE: u8 = 9;

/// Applies a re-reference: given the camera's mean error at each of the plan's points
/// (um, in [`Rereference::points_mm`]'s order), it updates the compensation and records
/// the reference; returns a line saying what it did (for the sender), or why it could
/// not.
pub type ReferenceHook<'a> = Box<dyn FnMut(&[[f64; 2]]) -> Result<String, String> + 'a>;

/// How the pass-through re-references the map with the camera: after the sender's
/// homing, and with `in_use` also every so often while the machine warms.
pub struct Rereference<'a> {
    /// Where the camera measures, machine mm, in this order: the map's reference point
    /// first, then (when the map reaches far enough) X's scale point and Y's.
    pub points_mm: Vec<[f64; 2]>,
    /// The last stretch to each point, from below on both axes, mm (as the scan
    /// approached its nodes).
    pub approach_mm: f64,
    /// Arrivals averaged at each point, each a new approach from below (at least one).
    pub arrivals: usize,
    /// Re-reference in use as well (no homing), or only after a homing (`None`).
    pub in_use: Option<InUse>,
    pub hook: ReferenceHook<'a>,
}

/// A re-reference in use: the screws grow as the machine warms, so the map's reference
/// (its shift and each axis's scale) is measured again every `every_s` seconds of the
/// session's clock. A due re-reference starts only at a safe moment: every sender line
/// answered, nothing of the gateway's in the controller, the controller `Idle` and its
/// machine Z at or above `clear_z_mm` (the tool clear of the work and the clamps). The
/// gateway never moves Z: its moves are XY rapids (`G53 G0`) at the Z where the tool is,
/// and it returns to the XY it left. Until such a moment it waits, and tells the sender
/// once.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InUse {
    pub every_s: f64,
    /// Machine Z (mm, `MPos`) at or above which the tool is clear.
    pub clear_z_mm: f64,
    /// When the first one is due, the session's clock (s): `every_s` less the age of
    /// the reference the session starts with, so an old one is measured again first.
    pub first_due_s: f64,
}

/// What the pass-through does after the sender's homing (`$H`), which moves the
/// machine's zero by a few um and so makes the map's reference stale.
pub enum AfterHoming<'a> {
    /// Nothing (a compensation that does not depend on the zero: the default).
    Pass,
    /// Re-reference with the camera before the next line: tell the sender, move to each
    /// point of the plan (machine mm, `G53`, approached from below), have the I/O loop
    /// measure a frame at each arrival ([`Proxy::frame_due`], [`Proxy::frame_measured`]),
    /// apply the means through the hook, return to where the homing left the machine,
    /// then release the next line. A failure locks motion out as `Refuse` does. With
    /// [`Rereference::in_use`], also in use ([`InUse`]).
    Reference(Rereference<'a>),
    /// No camera: motion lines are refused ([`UNREFERENCED_CODE`], with a message) until
    /// a reference is recorded ([`Proxy::referenced`]).
    Refuse,
}

/// Why a re-reference runs: what a failure means differs.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Why {
    /// The sender homed: the zero is not known until it is measured (a failure locks
    /// motion out).
    Homed,
    /// In use, on the interval: the last reference still holds (a failure of a frame
    /// is reported, the machine returns and the lines go on).
    InUse,
}

/// Where a re-reference stands.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Referencing {
    /// Nothing to do: lines flow.
    Idle,
    /// Homed: waiting for the controller's position at rest (where to return to).
    AwaitPosition,
    /// At rest at `back_mm`: the controller's modal state (`$G`) is asked first, so the
    /// sender's motion mode can be set again after the gateway's `G0` moves.
    AwaitModal {
        back_mm: [f64; 2],
        why: Why,
        /// In use, the machine Z it starts at (for the sender's message).
        z_mm: Option<f64>,
    },
    /// The gateway's moves to a point of the plan are on their way (`point`'s
    /// `arrival`-th arrival, from 0).
    Moving {
        back_mm: [f64; 2],
        why: Why,
        point: usize,
        arrival: usize,
    },
    /// At rest at a point of the plan: the I/O loop measures a frame.
    FrameDue {
        back_mm: [f64; 2],
        why: Why,
        point: usize,
        arrival: usize,
    },
    /// Returning to where the machine was.
    Returning,
    /// The zero is not known: motion is refused.
    Locked,
}

/// A sender line as it arrives, read as GRBL's `protocol_main_loop` reads it: spaces and
/// control characters dropped, `(...)` and `;` comments dropped, letters upper-cased,
/// and the line flagged as overflowing once more than [`LINE_BUFFER_SIZE`] - 1
/// characters are left (GRBL then answers `error:11` and executes nothing).
#[derive(Debug, Default)]
struct SenderLine {
    /// The bytes as sent, up to [`RAW_LINE_KEPT`].
    raw: Vec<u8>,
    raw_len: usize,
    /// What GRBL keeps of it.
    kept: Vec<u8>,
    paren_comment: bool,
    semicolon_comment: bool,
    overflow: bool,
}

/// A sender line complete: its text for the rewriter, or GRBL's answer to it.
#[derive(Debug)]
enum Received {
    Line(String),
    /// Refused as GRBL would refuse it: code and the gateway's message.
    Refused(u8, String),
}

impl SenderLine {
    fn push(&mut self, c: u8) {
        self.raw_len += 1;
        if self.raw.len() < RAW_LINE_KEPT {
            self.raw.push(c);
        }
        if self.paren_comment || self.semicolon_comment || self.overflow {
            if c == b')' {
                self.paren_comment = false;
            }
        } else if c <= b' ' || c == b'/' {
            // Whitespace, control characters; block delete is not supported.
        } else if c == b'(' {
            self.paren_comment = true;
        } else if c == b';' {
            self.semicolon_comment = true;
        } else if self.kept.len() >= LINE_BUFFER_SIZE - 1 {
            self.overflow = true;
        } else {
            self.kept.push(c.to_ascii_uppercase());
        }
    }

    /// The line ended (its number given for messages).
    fn finish(self, line: u64) -> Received {
        if self.overflow {
            return Received::Refused(
                11,
                format!(
                    "line {line}: longer than GRBL's line buffer ({} characters without \
                     spaces and comments; {} bytes sent); not sent",
                    LINE_BUFFER_SIZE - 1,
                    self.raw_len
                ),
            );
        }
        // GRBL 1.1h leaves `%` (program start and end) unsupported (protocol.c: "TODO:
        // Install '%' feature"): the parser meets it where a letter must be and answers
        // error:1 (expected command letter). So does the gateway, without sending it.
        if self.kept.first() == Some(&b'%') {
            return Received::Refused(
                1,
                format!(
                    "line {line}: `%` (a program delimiter) is not G-code to GRBL 1.1, \
                     which answers error:1; not sent"
                ),
            );
        }
        let bytes = match self.raw_len > self.raw.len() {
            true => self.kept,
            false => self.raw,
        };
        Received::Line(String::from_utf8_lossy(&bytes).into_owned())
    }
}

/// Fields of the controller's status reports that GRBL sends once (after a change, or
/// every so many reports) and that a report of the gateway's own took: they go into
/// the next report the sender gets, unless that report carries them itself.
#[derive(Debug, Default)]
struct OneTimeFields {
    wco: Option<Vec<f64>>,
    /// `Ov:` with the `A:` that came with it (GRBL 1.1 sends `A:` only beside `Ov:`; its
    /// absence there means every accessory is off).
    overrides: Option<([u16; 3], Option<String>)>,
    /// `A:` without `Ov:` (grblHAL, when an accessory changes).
    accessories: Option<String>,
    other: Vec<String>,
}

fn field_key(field: &str) -> &str {
    field.split(':').next().unwrap_or(field)
}

impl OneTimeFields {
    /// A report that does not go to the sender: keep what it alone carried.
    fn keep(&mut self, r: &StatusReport) {
        if let Some(w) = &r.wco {
            self.wco = Some(w.clone());
        }
        match (&r.overrides, &r.accessories) {
            (Some(ov), a) => {
                self.overrides = Some((*ov, a.clone()));
                self.accessories = None;
            }
            (None, Some(a)) => match &mut self.overrides {
                Some((_, with_ov)) => *with_ov = Some(a.clone()),
                None => self.accessories = Some(a.clone()),
            },
            (None, None) => {}
        }
        for f in &r.other {
            let key = field_key(f);
            if ONE_TIME_FIELDS.contains(&key) {
                self.other.retain(|o| field_key(o) != key);
                self.other.push(f.clone());
            }
        }
    }

    /// A report going to the sender: add what it lacks of the kept fields; forget them.
    fn merge_into(&mut self, r: &mut StatusReport) {
        let kept = std::mem::take(self);
        if r.wco.is_none() {
            r.wco = kept.wco;
        }
        if r.overrides.is_none() {
            if let Some((ov, a)) = kept.overrides {
                r.overrides = Some(ov);
                if r.accessories.is_none() {
                    r.accessories = a;
                }
            }
        }
        if r.accessories.is_none() {
            r.accessories = kept.accessories;
        }
        if r.overrides.is_none() {
            // `A:` alone (grblHAL): written among the other fields.
            if let Some(a) = r.accessories.take() {
                r.other.push(format!("A:{a}"));
            }
        }
        for f in kept.other {
            if !r.other.iter().any(|o| field_key(o) == field_key(&f)) {
                r.other.push(f);
            }
        }
    }
}

/// A piece of a sender line on its way to the controller.
#[derive(Debug)]
struct Piece {
    text: String,
    line: u64,
}

/// Where a session's lines ended up (reported when the sender leaves or the controller
/// is lost).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LineAccount {
    /// Lines answered `ok` (every piece planned by the controller).
    pub acknowledged: Vec<u64>,
    /// Lines answered with an error (refused by the gateway or the controller).
    pub refused: Vec<u64>,
    /// Lines with pieces in the controller's buffer, not all answered.
    pub in_controller: Vec<u64>,
    /// Lines received but not sent to the controller at all.
    pub not_sent: Vec<u64>,
}

/// Counters of a session.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ProxyStats {
    pub lines: u64,
    pub pieces_sent: u64,
    /// Status reports saying the controller was idle while pieces were waiting to go or
    /// waiting in its buffer: the planner starved because of the gateway.
    pub starvation_events: u64,
    /// Seconds from a line's arrival to its first piece going out, per line sent (the
    /// wait behind earlier lines' pieces included).
    pub latencies_s: Vec<f64>,
    /// Seconds the gateway spent rewriting each line: what it adds to a line's way.
    pub processing_s: Vec<f64>,
}

/// The pass-through state.
pub struct Proxy<'a> {
    rewriter: Box<dyn LineRewriter + 'a>,
    rx_buffer: usize,
    sender_partial: SenderLine,
    controller_partial: Vec<u8>,
    slots: VecDeque<Slot>,
    queue: VecDeque<Piece>,
    /// Lengths (with the newline) and lines of the pieces in the controller's buffer.
    in_flight: VecDeque<(usize, u64)>,
    in_flight_bytes: usize,
    next_line: u64,
    to_sender: Vec<u8>,
    to_controller: Vec<u8>,
    account: LineAccount,
    stats: ProxyStats,
    last_wco: Option<Vec<f64>>,
    starving: bool,
    /// The controller is gone: nothing more is sent, every line is refused.
    lost: bool,
    /// Sender lines held until the position is known again (after a homing, a jog or a
    /// reset the gateway asks the controller with `?` before it rewrites a move).
    deferred: VecDeque<(Received, f64)>,
    /// A `?` of the gateway's own is on its way.
    position_asked: bool,
    /// The sender sent `?` and has not had its report yet. GRBL reports only when asked,
    /// so the gateway's own polls are answered to it alone.
    sender_asked_status: bool,
    /// One-time report fields the gateway's own polls took from the sender.
    one_time: OneTimeFields,
    /// A `[MSG:gateway: ...]` for the sender before the answer to its first G-code line
    /// (which compensation and reference the program runs with).
    greeting: Option<String>,
    after_homing: AfterHoming<'a>,
    referencing: Referencing,
    /// The sums of the frames measured so far at each point of the re-reference.
    reference_sums: Vec<[f64; 2]>,
    /// When the next re-reference in use is due (the session's clock, s).
    in_use_due_s: Option<f64>,
    /// The sender was told a due re-reference waits for a safe moment.
    in_use_wait_said: bool,
    /// The latest time the caller gave (s).
    now_s: f64,
    /// The gateway's own lines of a re-reference in the controller's buffer.
    reference_lines: usize,
    /// The controller's modal words from its last `$G` reply.
    modal: Option<String>,
}

/// Marks a line of a re-reference in the controller's buffer (the gateway's own).
const OWN_REFERENCE: u64 = u64::MAX;

/// Marks the `$G` a re-reference asks first: its reply is the controller's modal state
/// now (kept for the return), not a state for the rewriter, which reads the sender's.
const OWN_MODAL: u64 = u64::MAX - 1;

/// Marks a line of the gateway's own (`$#`, `$G`) in the controller's buffer: its
/// answer and what comes before it are the gateway's, not the sender's.
const OWN: u64 = 0;

impl<'a> Proxy<'a> {
    /// The pass-through for a 3-axis compensation (an error map, a volumetric model).
    pub fn new(rewriter: Rewriter<'a>, compensation: &'a dyn Compensation) -> Self {
        Self::with_rewriter(Box::new(CartesianRewriter {
            rewriter,
            compensation,
        }))
    }

    /// The pass-through for any line rewriter (the rotary table's 5-axis one).
    pub fn with_rewriter(rewriter: Box<dyn LineRewriter + 'a>) -> Self {
        Self {
            rewriter,
            rx_buffer: RX_BUFFER,
            sender_partial: SenderLine::default(),
            controller_partial: Vec::new(),
            slots: VecDeque::new(),
            queue: VecDeque::new(),
            in_flight: VecDeque::new(),
            in_flight_bytes: 0,
            next_line: 1,
            to_sender: Vec::new(),
            to_controller: Vec::new(),
            account: LineAccount::default(),
            stats: ProxyStats::default(),
            last_wco: None,
            starving: false,
            lost: false,
            deferred: VecDeque::new(),
            position_asked: false,
            sender_asked_status: false,
            one_time: OneTimeFields::default(),
            greeting: None,
            after_homing: AfterHoming::Pass,
            referencing: Referencing::Idle,
            reference_sums: Vec::new(),
            in_use_due_s: None,
            in_use_wait_said: false,
            now_s: 0.0,
            reference_lines: 0,
            modal: None,
        }
    }

    /// What to do after the sender's homing ([`AfterHoming`]; default `Pass`), and in
    /// use ([`Rereference::in_use`]).
    pub fn after_homing(&mut self, what: AfterHoming<'a>) {
        self.in_use_due_s = match &what {
            AfterHoming::Reference(r) => r.in_use.map(|u| u.first_due_s),
            _ => None,
        };
        self.after_homing = what;
    }

    /// The plan of the re-reference, when there is one.
    fn plan(&self) -> Option<&Rereference<'a>> {
        match &self.after_homing {
            AfterHoming::Reference(r) => Some(r),
            _ => None,
        }
    }

    /// Where the I/O loop is to measure a frame now (machine mm: the stage is at rest
    /// there, a point of the re-reference); it answers with [`Self::frame_measured`].
    pub fn frame_due(&self) -> Option<[f64; 2]> {
        let Referencing::FrameDue { point, .. } = self.referencing else {
            return None;
        };
        self.plan().and_then(|r| r.points_mm.get(point).copied())
    }

    /// A frame's result (the camera's error at the point [`Self::frame_due`] gave, um):
    /// the next arrival or point, or after the last the means applied through the hook,
    /// then the machine returns and the lines go on. An error after a homing locks
    /// motion out; in use, the last reference holds and the machine returns.
    pub fn frame_measured(&mut self, seen_um: Result<[f64; 2], String>) {
        let Referencing::FrameDue {
            back_mm,
            why,
            point,
            arrival,
        } = self.referencing
        else {
            return;
        };
        let seen = match seen_um {
            Ok(s) => s,
            Err(e) => return self.reference_failed(why, back_mm, &e),
        };
        let Some((count, arrivals)) = self.plan().map(|r| (r.points_mm.len(), r.arrivals.max(1)))
        else {
            return self.reference_failed(why, back_mm, "no reference to take");
        };
        self.reference_sums.resize(count, [0.0; 2]);
        let sum = &mut self.reference_sums[point];
        *sum = [sum[0] + seen[0], sum[1] + seen[1]];
        let next = match (arrival + 1 < arrivals, point + 1 < count) {
            (true, _) => Some((point, arrival + 1)),
            (false, true) => Some((point + 1, 0)),
            (false, false) => None,
        };
        if let Some((point, arrival)) = next {
            return self.go_point(back_mm, why, point, arrival);
        }
        let n = arrivals as f64;
        let means: Vec<[f64; 2]> = std::mem::take(&mut self.reference_sums)
            .into_iter()
            .map(|s| [s[0] / n, s[1] / n])
            .collect();
        let applied = match &mut self.after_homing {
            AfterHoming::Reference(r) => (r.hook)(&means),
            _ => Err("no reference to take".into()),
        };
        match applied {
            Ok(what) => {
                self.message(&format!("referenced: {what}"));
                // A greeting not yet shown describes the map before this reference.
                self.greeting = None;
                self.go_back(back_mm);
            }
            Err(e) => self.reference_failed(why, back_mm, &e),
        }
    }

    /// The re-reference could not be taken: after a homing motion is locked out (the
    /// zero is not known); in use the last reference holds and the machine returns.
    fn reference_failed(&mut self, why: Why, back_mm: [f64; 2], e: &str) {
        self.reference_sums.clear();
        match why {
            Why::Homed => {
                self.message(&format!(
                    "the reference after homing failed: {e}; motion is refused until the \
                     machine is referenced (home again, or run gateway reference)"
                ));
                self.referencing = Referencing::Locked;
                self.release_deferred();
            }
            Why::InUse => {
                let every = self
                    .plan()
                    .and_then(|r| r.in_use)
                    .map_or(0.0, |u| u.every_s);
                self.message(&format!(
                    "the re-reference in use failed: {e}; the map keeps its last reference, \
                     the next try is in {every:.0} s"
                ));
                self.go_back(back_mm);
            }
        }
    }

    /// Back to where the machine was (its XY; Z was never moved), the sender's motion
    /// mode again, a dwell: the lines go on once it is answered.
    fn go_back(&mut self, back_mm: [f64; 2]) {
        let mut lines = vec![self.machine_move(back_mm)];
        // The gateway's G0 left the motion mode at G0: the sender's comes back.
        if let Some(m) = self.modal_motion() {
            lines.push(m);
        }
        lines.push("G4P0".to_string());
        self.own_lines(&lines);
        self.referencing = Referencing::Returning;
    }

    /// The caller's clock (s, the session's): a due re-reference in use asks where the
    /// machine is when nothing is on its way, and starts from the answer if it is safe
    /// ([`InUse`]). Called every status poll period.
    pub fn tick(&mut self, now_s: f64) {
        self.now_s = self.now_s.max(now_s);
        if self.in_use_due() && self.quiet() {
            self.ask_position();
        }
    }

    /// A re-reference in use is due and none is running.
    fn in_use_due(&self) -> bool {
        self.referencing == Referencing::Idle
            && !self.lost
            && self.in_use_due_s.is_some_and(|t| self.now_s >= t)
    }

    /// Every sender line answered and nothing on its way to the controller.
    fn quiet(&self) -> bool {
        self.slots.is_empty()
            && self.deferred.is_empty()
            && self.queue.is_empty()
            && self.in_flight.is_empty()
    }

    /// A status report while a re-reference in use is due: starts it when the machine
    /// is idle and the tool clear ([`InUse`]), else tells the sender once why it waits.
    fn maybe_in_use(&mut self, state: MachineState, machine: Option<&[f64]>) {
        let Some(u) = self.plan().and_then(|r| r.in_use) else {
            return;
        };
        if !(self.in_use_due() && self.quiet() && state == MachineState::Idle) {
            return;
        }
        match machine {
            Some(m) if m.len() >= 3 && m[2] >= u.clear_z_mm => {
                self.ask_modal([m[0], m[1]], Why::InUse, Some(m[2]));
            }
            _ if !self.in_use_wait_said => {
                self.in_use_wait_said = true;
                let z = machine
                    .and_then(|m| m.get(2))
                    .map_or("not reported".to_string(), |z| format!("{z:.3}"));
                self.message(&format!(
                    "a re-reference in use is due: it waits for the tool at or above machine \
                     Z {:.3} (now {z}) with the controller idle",
                    u.clear_z_mm
                ));
            }
            _ => {}
        }
    }

    /// A reference was recorded by other means: motion is allowed again.
    pub fn referenced(&mut self, what: &str) {
        if self.referencing == Referencing::Locked {
            self.message(&format!("referenced: {what}"));
            self.greeting = None;
            self.referencing = Referencing::Idle;
            self.release_deferred();
        }
    }

    fn message(&mut self, text: &str) {
        let clean: String = text
            .chars()
            .map(|c| match c {
                ']' => ')',
                '[' => '(',
                c if c.is_control() => ' ',
                c => c,
            })
            .collect();
        self.to_sender
            .extend_from_slice(format!("[MSG:gateway: {clean}]\r\n").as_bytes());
    }

    /// A rapid to machine point `p` (mm) in the controller's current units (G53 is in
    /// the units in force; a `$G` reply of G20 means inches).
    fn machine_move(&self, p: [f64; 2]) -> String {
        let inches = self
            .modal
            .as_deref()
            .is_some_and(|m| m.split_whitespace().any(|w| w == "G20"));
        match inches {
            true => format!("G53G0X{:.5}Y{:.5}", p[0] / 25.4, p[1] / 25.4),
            false => format!("G53G0X{:.4}Y{:.4}", p[0], p[1]),
        }
    }

    /// The motion mode word to restore after the gateway's own G0 moves: `G1` or `G80`
    /// (an arc mode cannot be set without its axis words; G0 needs nothing).
    fn modal_motion(&self) -> Option<String> {
        let m = self.modal.as_deref()?;
        m.split_whitespace()
            .find(|w| *w == "G1" || *w == "G80")
            .map(str::to_string)
    }

    /// Lines of the gateway's own for a re-reference, straight into the controller's
    /// buffer (a few short lines, sent when nothing else is in it).
    fn own_lines(&mut self, lines: &[String]) {
        for l in lines {
            self.to_controller.extend_from_slice(l.as_bytes());
            self.to_controller.push(b'\n');
            self.in_flight.push_back((l.len() + 1, OWN_REFERENCE));
            self.in_flight_bytes += l.len() + 1;
            self.reference_lines += 1;
        }
    }

    /// The sender's homing was acknowledged: the zero moved.
    fn homed(&mut self) {
        match &self.after_homing {
            AfterHoming::Pass => {}
            AfterHoming::Refuse => {
                self.message(
                    "homed: the machine's zero moved and no camera is there to re-reference \
                     the map; motion is refused (error:9) until a reference is recorded \
                     (gateway reference)",
                );
                self.referencing = Referencing::Locked;
            }
            AfterHoming::Reference(r) => {
                let at = r.points_mm.first().copied().unwrap_or([f64::NAN; 2]);
                let scale = match r.points_mm.len() {
                    1 => "",
                    _ => " and each axis's scale",
                };
                self.message(&format!(
                    "homed: the machine's zero moved; measuring the map's reference point \
                     (X{:.3} Y{:.3}){scale} with the camera before the next line",
                    at[0], at[1]
                ));
                self.referencing = Referencing::AwaitPosition;
                self.rewriter.forget_position();
                self.ask_position();
            }
        }
    }

    /// A re-reference begins: the controller's modal state first (`$G`), then the
    /// first point ([`Self::modal_answered`]).
    fn ask_modal(&mut self, back_mm: [f64; 2], why: Why, z_mm: Option<f64>) {
        self.reference_sums.clear();
        self.to_controller.extend_from_slice(b"$G\n");
        self.in_flight.push_back((3, OWN_MODAL));
        self.in_flight_bytes += 3;
        self.referencing = Referencing::AwaitModal { back_mm, why, z_mm };
    }

    /// The re-reference's `$G` answered. In use the gateway moves only when the
    /// controller's motion mode can be set again after its `G0` moves (`G0`, `G1` or
    /// `G80`: an arc or probe mode needs axis words), else it tries again a second later
    /// (the sender's next motion word changes it).
    fn modal_answered(&mut self, answer: Response) {
        let Referencing::AwaitModal { back_mm, why, z_mm } = self.referencing else {
            return;
        };
        if let Response::Error(code) = answer {
            return self.reference_failed(
                why,
                back_mm,
                &format!("the controller answered error:{code} to $G"),
            );
        }
        let motion = self
            .modal
            .as_deref()
            .and_then(|m| m.split_whitespace().next())
            .unwrap_or("G0")
            .to_string();
        if why == Why::InUse && !["G0", "G1", "G80"].contains(&motion.as_str()) {
            self.referencing = Referencing::Idle;
            self.in_use_due_s = Some(self.now_s + 1.0);
            if !self.in_use_wait_said {
                self.in_use_wait_said = true;
                self.message(&format!(
                    "a re-reference in use is due: it waits for the motion mode G0, G1 or G80 \
                     (now {motion}), which it can set again after its own G0 moves"
                ));
            }
            return self.release_deferred();
        }
        if why == Why::InUse {
            // In use there is always a plan with an interval and a Z (`maybe_in_use`).
            if let (Some(u), Some(z_mm)) = (self.plan().and_then(|r| r.in_use), z_mm) {
                self.message(&format!(
                    "re-referencing in use (every {:.0} s): measuring the map's reference \
                     with the camera at Z {z_mm:.3} before the next line",
                    u.every_s
                ));
            }
            self.in_use_wait_said = false;
            self.rewriter.forget_position();
        }
        self.go_point(back_mm, why, 0, 0);
    }

    /// To the plan's `point` for its `arrival`-th arrival (the controller at rest, the
    /// machine to return to at `back_mm`): the last stretch from below on both axes,
    /// then a dwell (answered once the moves have ended).
    fn go_point(&mut self, back_mm: [f64; 2], why: Why, point: usize, arrival: usize) {
        let Some((p, a)) = self
            .plan()
            .and_then(|r| Some((*r.points_mm.get(point)?, r.approach_mm.max(0.0))))
        else {
            return self.reference_failed(why, back_mm, "the plan has no such point");
        };
        let lines = vec![
            self.machine_move([p[0] - a, p[1] - a]),
            self.machine_move(p),
            "G4P0".to_string(),
        ];
        self.own_lines(&lines);
        self.referencing = Referencing::Moving {
            back_mm,
            why,
            point,
            arrival,
        };
    }

    /// Tell the sender `text` (as `[MSG:gateway: text]`) ahead of its first G-code line's
    /// answer: not at connect, where a strict sender reads `$I` or `$$` listings, but
    /// where GRBL's own feedback messages may come. `]` and line breaks are replaced.
    pub fn greet(&mut self, text: &str) {
        let clean: String = text
            .chars()
            .map(|c| match c {
                ']' => ')',
                '[' => '(',
                c if c.is_control() => ' ',
                c => c,
            })
            .collect();
        self.greeting = Some(clean);
    }

    /// What to send the controller first: its offsets (`$#`), its modal state (`$G`)
    /// and where it is (`?`). Their answers are the gateway's, not passed on.
    pub fn start(&mut self) {
        for own in ["$#", "$G"] {
            self.to_controller.extend_from_slice(own.as_bytes());
            self.to_controller.push(b'\n');
            self.in_flight.push_back((own.len() + 1, OWN));
            self.in_flight_bytes += own.len() + 1;
        }
        self.ask_position();
    }

    /// A status request of the gateway's own, while lines are on their way: the reports
    /// show whether the controller's planner ran dry (counted as starvation events). They
    /// reach the sender only when it asked too (GRBL reports only when asked; a sender may
    /// not expect a report inside a `$$` listing).
    pub fn poll_status(&mut self) {
        if self.busy() && !self.lost {
            self.to_controller.push(b'?');
        }
    }

    fn ask_position(&mut self) {
        if !self.position_asked && !self.lost {
            self.to_controller.push(b'?');
            self.position_asked = true;
        }
    }

    /// Whether the front of the controller's buffer is one of the gateway's own lines.
    fn own_line_pending(&self) -> bool {
        self.in_flight.front().is_some_and(|&(_, line)| line == OWN)
    }

    /// Bytes to write to the sender now.
    pub fn take_to_sender(&mut self) -> Vec<u8> {
        std::mem::take(&mut self.to_sender)
    }

    /// Bytes to write to the controller now.
    pub fn take_to_controller(&mut self) -> Vec<u8> {
        std::mem::take(&mut self.to_controller)
    }

    pub fn stats(&self) -> &ProxyStats {
        &self.stats
    }

    pub fn rewriter(&self) -> &dyn LineRewriter {
        self.rewriter.as_ref()
    }

    /// Bytes of the gateway's lines in the controller's RX buffer now.
    pub fn in_flight_bytes(&self) -> usize {
        self.in_flight_bytes
    }

    /// Lines of the gateway's in the controller's RX buffer now.
    pub fn in_flight_pieces(&self) -> usize {
        self.in_flight.len()
    }

    /// Bytes held for sender lines not yet rewritten: the line being received and the
    /// lines waiting for the position.
    pub fn held_bytes(&self) -> usize {
        let line = self.sender_partial.raw.len() + self.sender_partial.kept.len();
        let waiting: usize = self
            .deferred
            .iter()
            .map(|(r, _)| match r {
                Received::Line(t) => t.len(),
                Received::Refused(_, m) => m.len(),
            })
            .sum();
        line + waiting
    }

    /// Whether lines are waiting to go or waiting for the controller.
    pub fn busy(&self) -> bool {
        !self.slots.is_empty()
    }

    /// Where every line received so far stands.
    pub fn account(&self) -> LineAccount {
        let mut a = self.account.clone();
        let queued: Vec<u64> = self.queue.iter().map(|p| p.line).collect();
        for s in &self.slots {
            if s.first_sent_s.is_some() {
                a.in_controller.push(s.line);
            } else if s.outstanding > 0 || queued.contains(&s.line) {
                a.not_sent.push(s.line);
            }
        }
        // Held lines get their numbers when they are read; these are the next ones.
        a.not_sent
            .extend((0..self.deferred.len() as u64).map(|k| self.next_line + k));
        a
    }

    /// Bytes from the sender, at `now_s` (the caller's clock, for latency figures).
    pub fn from_sender(&mut self, bytes: &[u8], now_s: f64) {
        self.now_s = self.now_s.max(now_s);
        for &b in bytes {
            // Most bytes are plain text: only these four below 0x80 are real-time.
            let kind = match b {
                b'?' | b'!' | b'~' | 0x18 | 0x80.. => classify(b),
                _ => RxByte::Buffered(b),
            };
            match kind {
                RxByte::Realtime(rt) => {
                    if self.lost {
                        continue;
                    }
                    self.to_controller.push(rt.byte());
                    if rt == Realtime::StatusQuery {
                        self.sender_asked_status = true;
                    }
                    if rt.byte() == 0x18 {
                        // Soft reset: the controller drops its buffer and modal state;
                        // so does the gateway (the sender knows from the banner).
                        self.drop_pending();
                        self.rewriter.controller_reset();
                        self.position_asked = false;
                        self.sender_asked_status = false;
                    }
                }
                RxByte::Buffered(b'\n' | b'\r') => {
                    let line = std::mem::take(&mut self.sender_partial);
                    // Its number once read: after the ones held before it.
                    let number = self.next_line + self.deferred.len() as u64;
                    self.deferred.push_back((line.finish(number), now_s));
                    self.release_deferred();
                }
                RxByte::Buffered(b) => self.sender_partial.push(b),
                // GRBL drops extended bytes it does not know; so does the gateway.
                RxByte::Discarded => {}
            }
        }
        self.pump(now_s);
    }

    /// Rewrite held lines while the position is known (or the controller lost: they
    /// are refused); else ask the controller once nothing is outstanding.
    fn release_deferred(&mut self) {
        if !matches!(self.referencing, Referencing::Idle | Referencing::Locked) {
            return;
        }
        while let Some((received, _)) = self.deferred.front() {
            let needs_position = !self.rewriter.position_known() && !self.lost;
            if let Received::Line(text) = received {
                if needs_position && !text.trim_start().starts_with('$') && !text.trim().is_empty()
                {
                    if self.slots.is_empty() && !self.own_line_pending() {
                        self.ask_position();
                    }
                    return;
                }
            }
            let (received, at) = self.deferred.pop_front().expect("front exists");
            self.sender_line(received, at);
        }
    }

    /// Whether the gateway takes more bytes from the sender now: not while
    /// [`MAX_UNANSWERED_LINES`] lines wait for their answers.
    pub fn accepts_sender_bytes(&self) -> bool {
        self.slots.len() + self.deferred.len() < MAX_UNANSWERED_LINES
    }

    fn sender_line(&mut self, received: Received, now_s: f64) {
        let line = self.next_line;
        self.next_line += 1;
        self.stats.lines += 1;
        let mut slot = Slot {
            line,
            outstanding: 0,
            error: None,
            received_s: now_s,
            first_sent_s: None,
            homing: false,
        };
        let text = match received {
            Received::Line(text) => text,
            Received::Refused(code, why) => {
                if !self.lost {
                    let msg = format!("[MSG:gateway: {why}]\r\n");
                    self.to_sender.extend_from_slice(msg.as_bytes());
                }
                slot.error = Some(if self.lost { 9 } else { code });
                String::new()
            }
        };
        let command = text.trim_start();
        let system = command.starts_with('$');
        if self.lost {
            slot.error = Some(9);
        } else if slot.error.is_some() || text.trim().is_empty() {
            // GRBL answers an empty line with `ok` (senders use it to sync).
        } else if self.referencing == Referencing::Locked && !system {
            self.message(&format!(
                "line {line}: the machine was homed and the map is not referenced again: \
                 motion is refused until it is (gateway reference); not sent"
            ));
            slot.error = Some(UNREFERENCED_CODE);
        } else {
            if !text.trim_start().starts_with('$') {
                if let Some(g) = self.greeting.take() {
                    let msg = format!("[MSG:gateway: {g}]\r\n");
                    self.to_sender.extend_from_slice(msg.as_bytes());
                }
            }
            let t0 = std::time::Instant::now();
            let rewritten = self.rewriter.line(&text, line as usize);
            self.stats.processing_s.push(t0.elapsed().as_secs_f64());
            slot.homing = system && command.to_ascii_uppercase().starts_with("$H");
            match rewritten {
                Ok(pieces) => {
                    for p in pieces {
                        if protocol::grbl::gcode::filter_bytes(p.as_bytes())
                            .0
                            .is_empty()
                            && !p.trim_start().starts_with('$')
                        {
                            // A comment-only line: nothing to send.
                            continue;
                        }
                        slot.outstanding += 1;
                        self.queue.push_back(Piece { text: p, line });
                    }
                }
                Err(e) => {
                    let msg = format!("[MSG:gateway: {e}]\r\n");
                    self.to_sender.extend_from_slice(msg.as_bytes());
                    slot.error = Some(refusal_code(&e));
                }
            }
        }
        self.slots.push_back(slot);
        self.answer_ready();
    }

    /// Send queued pieces while they fit in the controller's RX buffer.
    fn pump(&mut self, now_s: f64) {
        if self.lost {
            return;
        }
        while let Some(p) = self.queue.front() {
            let len = p.text.len() + 1;
            if self.in_flight_bytes + len > self.rx_buffer && !self.in_flight.is_empty() {
                break;
            }
            let p = self.queue.pop_front().expect("front exists");
            self.to_controller.extend_from_slice(p.text.as_bytes());
            self.to_controller.push(b'\n');
            self.in_flight.push_back((len, p.line));
            self.in_flight_bytes += len;
            self.stats.pieces_sent += 1;
            if let Some(s) = self.slots.iter_mut().find(|s| s.line == p.line) {
                if s.first_sent_s.is_none() {
                    s.first_sent_s = Some(now_s);
                    self.stats.latencies_s.push(now_s - s.received_s);
                }
            }
        }
    }

    /// Bytes from the controller.
    pub fn from_controller(&mut self, bytes: &[u8], now_s: f64) {
        self.now_s = self.now_s.max(now_s);
        for &b in bytes {
            if b != b'\n' {
                self.controller_partial.push(b);
                continue;
            }
            let raw = std::mem::take(&mut self.controller_partial);
            let text = String::from_utf8_lossy(&raw);
            let text = text.trim_end_matches('\r');
            if !text.is_empty() {
                self.controller_line(text);
            }
        }
        self.pump(now_s);
    }

    fn controller_line(&mut self, raw: &str) {
        match Response::parse(raw) {
            Response::Ok | Response::Error(_) => {
                let Some((len, line)) = self.in_flight.pop_front() else {
                    // An answer to nothing we sent: pass it on as it came.
                    self.pass_on(raw);
                    return;
                };
                self.in_flight_bytes -= len;
                if line == OWN {
                    self.release_deferred();
                    return;
                }
                if line == OWN_REFERENCE {
                    self.reference_line_answered(Response::parse(raw));
                    return;
                }
                if line == OWN_MODAL {
                    self.modal_answered(Response::parse(raw));
                    return;
                }
                if let Some(s) = self.slots.iter_mut().find(|s| s.line == line) {
                    s.outstanding -= 1;
                    if let Response::Error(code) = Response::parse(raw) {
                        s.error.get_or_insert(code);
                    }
                }
                self.answer_ready();
                self.release_deferred();
            }
            Response::Parameter { name, value } if self.own_line_pending() => {
                self.own_offset(&name, &value);
            }
            Response::ParserState(words)
                if self.in_flight.front().is_some_and(|&(_, l)| l == OWN_MODAL) =>
            {
                self.modal = Some(words);
            }
            Response::ParserState(words) if self.own_line_pending() => {
                // A $G reply the controller would not refuse; a failure leaves defaults.
                self.rewriter.sync_modal(&words);
                self.modal = Some(words);
            }
            // Everything else a `$#` prints (`[G59.1:]`..`[G59.3:]`, `[G51:]`, `[T:...]`,
            // `[TLR:]` of grblHAL, `[HOME:]`, ...): the gateway's own too.
            Response::Other(ref line) if self.own_line_pending() && line.starts_with('[') => {}
            Response::Status(report) => self.status(report),
            Response::Banner { .. } => {
                // The controller restarted: its buffer is gone, nothing is resent.
                self.drop_pending();
                self.rewriter.controller_reset();
                self.position_asked = false;
                self.one_time = OneTimeFields::default();
                self.pass_on(raw);
            }
            _ => self.pass_on(raw),
        }
    }

    /// One of a re-reference's own lines answered: at the end of the moves the frame is
    /// due; at the end of the return the lines go on; an error locks motion out.
    fn reference_line_answered(&mut self, answer: Response) {
        self.reference_lines = self.reference_lines.saturating_sub(1);
        if let Response::Error(code) = answer {
            self.message(&format!(
                "the reference after homing failed: the controller answered error:{code} to \
                 the gateway's move; motion is refused until the machine is referenced"
            ));
            self.referencing = Referencing::Locked;
        }
        if self.reference_lines > 0 {
            return;
        }
        match self.referencing {
            Referencing::Moving {
                back_mm,
                why,
                point,
                arrival,
            } => {
                self.referencing = Referencing::FrameDue {
                    back_mm,
                    why,
                    point,
                    arrival,
                };
            }
            Referencing::Returning => {
                self.referencing = Referencing::Idle;
                // The next one in use counts from this one's end (a homing's too).
                if let Some(u) = self.plan().and_then(|r| r.in_use) {
                    self.in_use_due_s = Some(self.now_s + u.every_s);
                }
                // The position is learnt again before the next move.
                self.rewriter.forget_position();
                self.release_deferred();
            }
            _ => self.release_deferred(),
        }
    }

    /// Answer, in order, every line whose pieces are all answered.
    fn answer_ready(&mut self) {
        while let Some(s) = self.slots.front() {
            let queued = self.queue.iter().any(|p| p.line == s.line);
            if s.outstanding > 0 || queued {
                break;
            }
            let s = self.slots.pop_front().expect("front exists");
            match s.error {
                None => {
                    self.to_sender.extend_from_slice(b"ok\r\n");
                    self.account.acknowledged.push(s.line);
                    if s.homing {
                        self.homed();
                    }
                }
                Some(code) => {
                    self.to_sender
                        .extend_from_slice(format!("error:{code}\r\n").as_bytes());
                    self.account.refused.push(s.line);
                }
            }
        }
    }

    /// A status report with the controller's (compensated) position turned back into
    /// the programmed one; the gateway also learns the position when all is idle.
    fn status(&mut self, mut report: StatusReport) {
        // Whatever it says, the question was answered; asked again if still needed.
        self.position_asked = false;
        if let Some(w) = &report.wco {
            self.last_wco = Some(w.clone());
        }
        let idle = report.state == MachineState::Idle;
        let waiting = !self.queue.is_empty() || !self.in_flight.is_empty();
        if idle && waiting && !self.starving {
            self.stats.starvation_events += 1;
        }
        self.starving = idle && waiting;
        let machine = report.machine_position(self.last_wco.as_deref());
        if self.referencing == Referencing::AwaitPosition
            && report.state == MachineState::Idle
            && self.in_flight.is_empty()
        {
            if let Some(m) = machine.as_ref().filter(|m| m.len() >= 2) {
                self.ask_modal([m[0], m[1]], Why::Homed, None);
            }
        }
        self.maybe_in_use(report.state, machine.as_deref());
        if self.referencing == Referencing::AwaitPosition {
            // Not at rest yet (or lines of the sender's `$` commands on their way).
            self.ask_position();
        }
        if let Some(command) = machine {
            // At rest with nothing owed, the reported position is where the next move
            // starts (in Alarm too: GRBL then refuses moves itself, with error:9).
            let at_rest = matches!(
                report.state,
                MachineState::Idle | MachineState::Alarm | MachineState::Check
            ) && self.slots.is_empty();
            let nominal = self.rewriter.nominal_position(&command, at_rest);
            for (shown, (n, c)) in report.position.iter_mut().zip(nominal.iter().zip(&command)) {
                *shown += n - c;
            }
        }
        // GRBL's decimals for mm reports ($13=0, the default; the gateway's map is in mm).
        if std::mem::take(&mut self.sender_asked_status) {
            self.one_time.merge_into(&mut report);
            let line = report.to_line(3);
            self.to_sender.extend_from_slice(line.as_bytes());
            self.to_sender.extend_from_slice(b"\r\n");
        } else {
            self.one_time.keep(&report);
        }
        self.release_deferred();
    }

    /// One `[G54:x,y,z]` line of the gateway's own `$#`.
    fn own_offset(&mut self, name: &str, value: &str) {
        let Some(k) = ["G54", "G55", "G56", "G57", "G58", "G59"]
            .iter()
            .position(|g| *g == name)
        else {
            return;
        };
        let v: Vec<f64> = value
            .split(',')
            .filter_map(|x| x.trim().parse().ok())
            .collect();
        self.rewriter.set_work_offset(k, &v);
    }

    fn pass_on(&mut self, raw: &str) {
        self.to_sender.extend_from_slice(raw.as_bytes());
        self.to_sender.extend_from_slice(b"\r\n");
    }

    /// Forget everything not yet answered (after a reset): no answers are owed, nothing
    /// is resent.
    fn drop_pending(&mut self) {
        for s in self.slots.drain(..) {
            if s.first_sent_s.is_some() {
                self.account.in_controller.push(s.line);
            } else {
                self.account.not_sent.push(s.line);
            }
        }
        self.queue.clear();
        self.in_flight.clear();
        self.in_flight_bytes = 0;
        self.reference_lines = 0;
        self.reference_sums.clear();
        if self.referencing != Referencing::Idle {
            // A reset in the middle of a re-reference: the zero is not known.
            self.referencing = Referencing::Locked;
        }
        for (_, _) in self.deferred.drain(..) {
            let line = self.next_line;
            self.next_line += 1;
            self.account.not_sent.push(line);
        }
    }

    /// The controller is gone: the sender is told with an alarm, lines owed an answer
    /// get `error:9` (locked), nothing is resent. Returns where every line stood.
    pub fn controller_lost(&mut self, why: &str) -> LineAccount {
        let account = self.account();
        self.lost = true;
        self.queue.clear();
        self.in_flight.clear();
        self.in_flight_bytes = 0;
        self.to_sender.extend_from_slice(
            format!("[MSG:gateway: controller lost: {why}]\r\nALARM:3\r\n").as_bytes(),
        );
        for s in &mut self.slots {
            s.outstanding = 0;
            s.error.get_or_insert(9);
        }
        self.answer_ready();
        self.rewriter.forget_position();
        account
    }

    /// The sender is gone mid-stream: hold the motion (feed hold) and report where every
    /// line stood. Queued pieces are dropped, not sent.
    pub fn sender_lost(&mut self) -> LineAccount {
        let account = self.account();
        if self.busy() && !self.lost {
            self.to_controller.push(b'!');
        }
        self.queue.clear();
        account
    }
}
