//! The program rewriter: a user's G-code in, the same program out with every move
//! replaced by the commands that put the tool on the programmed path.
//!
//! A [`Compensation`] (the error map, the volumetric model, the rotary-table model)
//! answers one question: which command puts the tool on this nominal point? The rewriter
//! does the rest, block by block:
//!
//! 1. reads the block as the controller would: GRBL 1.1's own interpreter
//!    ([`protocol::grbl::gcode::Interpreter`]) gives the nominal moves in machine
//!    coordinates (units, G90/G91, G54-G59, G92, G53, planes, arcs as chords) and refuses
//!    what the controller would refuse, naming the line, before anything is written;
//! 2. splits each feed move where needed: the controller moves in a straight line between
//!    two commands, while the compensated path bends with the machine's errors, so a move
//!    is cut in halves until, at the quarter points and the middle of every piece, the
//!    straight line between the commands stays within the tolerance of the command the
//!    model gives for the nominal point there ([`split`]); rapids (G0) are not split,
//!    only their end is corrected (their path is not controlled, as on any CNC); arcs
//!    become chords within half the tolerance and each chord is split within the other
//!    half;
//! 3. follows each axis's *command* along the move, not only its programmed direction:
//!    where the command of any axis turns back (a reversal, or the correction of an axis
//!    the program leaves still creeping up and then back), the move is cut there, the
//!    axis first takes up its backlash on the spot (the model's command for the other
//!    side at the same point), and the rest of the move is commanded for that side
//!    ([`split::turns`]). A retreat smaller than half the tolerance is not followed (the
//!    map's own noise; the axis stays at most that far in its backlash), and what is left
//!    of it is carried into the next moves, so a creep spread over many short moves is
//!    seen. Bound: at most one turn per axis per sample (a quarter of the model's feature
//!    length), and at most (the travel of the axis's correction back and forth along the
//!    move) / (T / 2) turns per axis;
//! 4. moves the values of G92 and G10 L20 by the correction at the present point (the
//!    controller takes its corrected position for the present point), so the offset set
//!    is the one the program meant;
//! 5. checks every command against the correction bound and the soft limits;
//! 6. writes the block back with only the axis words changed (comments, line numbers,
//!    feeds, spindle words and spacing kept), the extra pieces as `G1` lines after it.
//!
//! Positions: the rewriter knows an axis's position once an absolute move (G90 or G53)
//! has named it, or from [`Options::start`]. A move of a compensated axis whose position
//! is not known is refused (no correction on a guess); so is an incremental move from an
//! unknown position. After homing (`$H`), a jog, a probe or G28/G30 the position is not
//! known again until an absolute move names it.
//!
//! Worked example (error map, machine = work coordinates): the map says the tool lands
//! 12 um short in X near X=50, so `G1 X50 Y20 F600` becomes `G1 X50.0120 Y20.0000 F600`
//! (4 decimals in mm, 5 in inches); a 40 mm move across a 5 mm-lead screw error of 2 um
//! becomes about 40 pieces at T = 0.5 um.

pub mod dialect;
pub mod fanuc;
pub mod ngc;
pub mod programs;
mod rewriter;
pub mod split;

pub use protocol::grbl::gcode::N_AXIS;
pub use rewriter::{
    rewrite_program, Limits, Note, Options, Report, RewriteError, RewriteErrorKind, Rewriter,
};

/// A position of every axis the controller drives (X, Y, Z), machine coordinates, mm.
pub type Pose = [f64; N_AXIS];

/// The axis letters, in [`Pose`] order.
pub const AXIS_LETTERS: [char; N_AXIS] = ['X', 'Y', 'Z'];

/// The side the last move of an axis came from (backlash depends on it).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Approach {
    /// From below (the last move was in +).
    Forward,
    /// From above (the last move was in -).
    Reverse,
}

/// A model of the machine that gives the command putting the tool on a nominal point.
pub trait Compensation {
    /// What it is, for reports ("error map stage-1 v3").
    fn describe(&self) -> String;
    /// The axes (indices into [`Pose`]) whose commands it changes; the others are passed
    /// through as programmed.
    fn axes(&self) -> &[usize];
    /// The shortest distance (mm) over which the model's errors can turn: the node
    /// spacing of a map. Splitting probes a piece at least four times per feature length.
    fn feature_length_mm(&self) -> f64 {
        f64::INFINITY
    }
    /// The command that puts the tool on `nominal` when each axis arrives from the side
    /// `approach` gives. Refuses (with a reason) rather than extrapolate.
    fn command_for(&self, nominal: &Pose, approach: &[Approach; N_AXIS]) -> Result<Pose, String>;
    /// The same from a first guess of the command (the rewriter knows a close one: the
    /// straight line between two neighbouring commands). Iterative inverses start there.
    fn command_near(
        &self,
        nominal: &Pose,
        approach: &[Approach; N_AXIS],
        _guess: &Pose,
    ) -> Result<Pose, String> {
        self.command_for(nominal, approach)
    }
    /// Where the tool really is for a command: the forward model (the pass-through turns
    /// the controller's reported position back into the programmed one with it).
    /// Refuses outside the model.
    fn tool_for(&self, command: &Pose, _approach: &[Approach; N_AXIS]) -> Result<Pose, String> {
        Ok(*command)
    }
}

/// No correction at all: the rewrite only re-checks and re-writes (a baseline).
#[derive(Clone, Copy, Debug, Default)]
pub struct Identity;

impl Compensation for Identity {
    fn describe(&self) -> String {
        "no compensation".into()
    }
    fn axes(&self) -> &[usize] {
        &[]
    }
    fn command_for(&self, nominal: &Pose, _: &[Approach; N_AXIS]) -> Result<Pose, String> {
        Ok(*nominal)
    }
}

#[cfg(test)]
mod tests;
