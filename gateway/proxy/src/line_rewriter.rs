//! What the pass-through needs of a program rewriter, and the two it has: the 3-axis
//! rewriter of `rewrite` (error maps, volumetric models: X Y Z) and the 5-axis one of
//! `rotary` (the A/C tilting table: X Y Z A C on a grblHAL six-axis build, X Y Z A B C,
//! whose B has no travel).

use protocol::nc::{Block, Program};
use rewrite::{Compensation, Pose, RewriteError, RewriteErrorKind, Rewriter, N_AXIS};
use rotary::rewrite::RotaryRewriter;
use rotary::Axes;

/// A rewriter the pass-through drives line by line, keeping it in step with the
/// controller.
pub trait LineRewriter {
    /// The lines to send instead of `text` (sender line `line_no`); on an error nothing
    /// changes.
    fn line(&mut self, text: &str, line_no: usize) -> Result<Vec<String>, RewriteError>;
    /// Whether every compensated axis's position is known (else the gateway asks the
    /// controller before it rewrites a move).
    fn position_known(&self) -> bool;
    fn forget_position(&mut self);
    /// The controller was reset: modal state back to its defaults, position unknown.
    fn controller_reset(&mut self);
    /// The controller's modal words (inside its `$G` reply's `[GC:...]`).
    fn sync_modal(&mut self, words: &str);
    /// One of the controller's stored work offsets (`k` 0 = G54), as `$#` reports it.
    fn set_work_offset(&mut self, k: usize, values: &[f64]);
    /// The controller's machine position (every axis it reports) in programmed terms,
    /// the same length; `at_rest` (idle with nothing owed): also where the next move
    /// starts. Axes the model cannot turn back are shown as the controller has them.
    fn nominal_position(&mut self, command: &[f64], at_rest: bool) -> Vec<f64>;
    /// The largest correction written so far (um) and the pieces added by splitting.
    fn summary(&self) -> (f64, usize);
}

/// The 3-axis rewriter with the compensation it rewrites for.
pub struct CartesianRewriter<'a> {
    pub rewriter: Rewriter<'a>,
    pub compensation: &'a dyn Compensation,
}

impl LineRewriter for CartesianRewriter<'_> {
    fn line(&mut self, text: &str, line_no: usize) -> Result<Vec<String>, RewriteError> {
        self.rewriter.line(text, line_no)
    }

    fn position_known(&self) -> bool {
        self.rewriter.position_known()
    }

    fn forget_position(&mut self) {
        self.rewriter.forget_position();
    }

    fn controller_reset(&mut self) {
        self.rewriter.controller_reset();
    }

    fn sync_modal(&mut self, words: &str) {
        // A reply the gateway cannot read leaves the defaults.
        let _ = self.rewriter.sync_modal(words);
    }

    fn set_work_offset(&mut self, k: usize, values: &[f64]) {
        if k < 6 && values.len() >= N_AXIS {
            let mut offsets = self.rewriter.work_offsets();
            offsets[k].copy_from_slice(&values[..N_AXIS]);
            self.rewriter.set_work_offsets(offsets);
        }
    }

    fn nominal_position(&mut self, command: &[f64], at_rest: bool) -> Vec<f64> {
        let mut out = command.to_vec();
        if command.len() < N_AXIS {
            return out;
        }
        let mut c: Pose = [0.0; N_AXIS];
        c.copy_from_slice(&command[..N_AXIS]);
        let approach = self.rewriter.approach();
        // Outside the map (e.g. at the home switches) the position is shown as the
        // controller has it.
        let nominal = self.compensation.tool_for(&c, &approach).unwrap_or(c);
        if at_rest {
            self.rewriter.set_position(nominal, c);
        }
        out[..N_AXIS].copy_from_slice(&nominal);
        out
    }

    fn summary(&self) -> (f64, usize) {
        let r = self.rewriter.report();
        (r.largest_correction_um, r.segments_added)
    }
}

/// The 5-axis rewriter of the rotary table, behind a controller reporting X Y Z A B C.
pub struct FiveAxisRewriter<'a> {
    pub rewriter: RotaryRewriter<'a>,
}

impl<'a> FiveAxisRewriter<'a> {
    pub fn new(rewriter: RotaryRewriter<'a>) -> Self {
        Self { rewriter }
    }
}

/// The grblHAL six-axis slots of X Y Z A C (B, slot 4, has no travel on this machine).
const SLOTS: [usize; 5] = [0, 1, 2, 3, 5];

impl LineRewriter for FiveAxisRewriter<'_> {
    fn line(&mut self, text: &str, line_no: usize) -> Result<Vec<String>, RewriteError> {
        // `$` lines (settings, `$I`, `$G`, `$#`, homing, jogs) go to the controller as
        // written, as in the 3-axis rewriter; homing and jogs leave the position unknown.
        let trimmed = text.trim_start();
        if trimmed.starts_with('$') {
            let upper = trimmed.to_ascii_uppercase();
            if upper.starts_with("$H") || upper.starts_with("$J=") {
                self.rewriter.forget_position();
            }
            return Ok(vec![trimmed.to_string()]);
        }
        let block = Block::parse(text, line_no).map_err(|e| RewriteError {
            line: line_no,
            kind: RewriteErrorKind::Syntax(e),
        })?;
        let blocks = self
            .rewriter
            .block(block, line_no)
            .map_err(|e| RewriteError {
                line: line_no,
                kind: RewriteErrorKind::Model(match e {
                    rotary::rewrite::RewriteError::Refused { why, .. } => why,
                    other => other.to_string(),
                }),
            })?;
        Ok(blocks
            .into_iter()
            .map(|b| {
                Program { blocks: vec![b] }
                    .to_string()
                    .trim_end_matches(['\r', '\n'])
                    .to_string()
            })
            .collect())
    }

    fn position_known(&self) -> bool {
        self.rewriter.position_known()
    }

    fn forget_position(&mut self) {
        self.rewriter.forget_position();
    }

    fn controller_reset(&mut self) {
        self.rewriter.controller_reset();
    }

    fn sync_modal(&mut self, words: &str) {
        self.rewriter.sync_modal(words);
    }

    fn set_work_offset(&mut self, k: usize, values: &[f64]) {
        self.rewriter.set_work_offset(k, values);
    }

    fn nominal_position(&mut self, command: &[f64], at_rest: bool) -> Vec<f64> {
        let mut out = command.to_vec();
        if command.len() < 6 {
            return out;
        }
        let c = Axes::new(command[0], command[1], command[2], command[3], command[5]);
        let Ok(n) = self.rewriter.nominal_of(&c) else {
            return out;
        };
        if at_rest {
            self.rewriter.set_position(n, c);
        }
        for (slot, v) in SLOTS.iter().zip([n.x, n.y, n.z, n.a, n.c]) {
            out[*slot] = v;
        }
        out
    }

    fn summary(&self) -> (f64, usize) {
        let report = &self.rewriter.report;
        let largest_um = report
            .points
            .iter()
            .map(|p| {
                let (n, c) = (&p.nominal, &p.command);
                ((c.x - n.x).powi(2) + (c.y - n.y).powi(2) + (c.z - n.z).powi(2)).sqrt() * 1000.0
            })
            .fold(0.0, f64::max);
        (largest_um, report.pieces_added)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rotary::rewrite::RewriteOptions;
    use rotary::{LocationErrors, MachineConstants, RotaryMachine};

    fn table() -> RotaryMachine {
        RotaryMachine::with_errors(MachineConstants::default(), LocationErrors::paper())
    }

    fn rewriter(model: &RotaryMachine, bound_mm: f64) -> FiveAxisRewriter<'_> {
        let opts = RewriteOptions {
            max_correction_mm: bound_mm,
            ..RewriteOptions::default()
        };
        FiveAxisRewriter::new(RotaryRewriter::new(model, opts))
    }

    #[test]
    fn the_controller_state_from_its_replies_refuses_what_would_be_read_otherwise() {
        let model = table();
        let mut r = rewriter(&model, 2.0);
        // The controller reads incrementally: a move is refused until G90.
        r.sync_modal("G0 G54 G17 G21 G91 G94 M5 M9 T0 F0 S0");
        let e = r.line("G0 X1 Y2 Z-150 A0 C0", 1).unwrap_err();
        assert!(e.to_string().contains("G91"), "{e}");
        assert_eq!(crate::refusal_code(&e), 33);
        let out = r.line("G90 G0 X1 Y2 Z-150 A0 C0", 2).unwrap();
        assert_eq!(out.len(), 1);
        assert!(out[0].starts_with("G90 G0 X"), "{out:?}");
        // A work offset on the controller: the table's model is in machine coordinates.
        r.set_work_offset(1, &[5.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
        assert!(r.line("G55", 3).is_ok());
        let e = r.line("G1 X2 F100", 4).unwrap_err();
        assert!(e.to_string().contains("G55"), "{e}");
        // Back to G54 (zero): accepted; a reset forgets the position.
        assert!(r.line("G54 G1 X2 F100", 5).is_ok());
        assert!(r.position_known());
        r.controller_reset();
        assert!(!r.position_known());
    }

    /// What senders send at connect (`$I`, `$$`, `$G`) goes through as written; homing
    /// and jogs leave the position unknown (found by the independent Python sender,
    /// whose `$I` the 5-axis pass-through refused).
    #[test]
    fn system_lines_go_through_and_homing_or_jogging_forgets_the_position() {
        let model = table();
        let mut r = rewriter(&model, 2.0);
        for l in ["$I", "$$", "$G", "$#", "$X"] {
            assert_eq!(r.line(l, 1).unwrap(), vec![l.to_string()]);
        }
        assert!(r.line("G90 G0 X1 Y2 Z-150 A0 C0", 2).is_ok());
        assert!(r.position_known());
        assert_eq!(r.line("$J=G91 X1 F100", 3).unwrap(), vec!["$J=G91 X1 F100"]);
        assert!(!r.position_known());
        assert!(r.line("G90 G0 X1 Y2 Z-150 A0 C0", 4).is_ok());
        r.line("$H", 5).unwrap();
        assert!(!r.position_known());
    }

    #[test]
    fn a_correction_beyond_the_bound_is_refused_and_changes_nothing() {
        let model = table();
        // The paper's delta_ZA moves the tip by tenths of a millimetre at A = 45°.
        let mut r = rewriter(&model, 0.05);
        let e = r.line("G0 X0 Y0 Z-170 A45 C0", 1).unwrap_err();
        assert!(e.to_string().contains("beyond the bound"), "{e}");
        assert!(!r.position_known(), "nothing learned from a refused line");
        let mut wide = rewriter(&model, 2.0);
        assert!(wide.line("G0 X0 Y0 Z-170 A45 C0", 1).is_ok());
        assert!(wide.summary().0 > 50.0, "{:?}", wide.summary());
    }

    #[test]
    fn the_reported_position_turns_back_into_the_programmed_one() {
        let model = table();
        let mut r = rewriter(&model, 2.0);
        let nominal = Axes::new(10.0, -5.0, -170.0, 30.0, 60.0);
        let c = model.command_for(&nominal).unwrap();
        let shown = r.nominal_position(&[c.x, c.y, c.z, c.a, 0.0, c.c], true);
        for (got, want) in [shown[0], shown[1], shown[2], shown[3], shown[5]]
            .iter()
            .zip([10.0, -5.0, -170.0, 30.0, 60.0])
        {
            assert!((got - want).abs() < 1e-6, "{shown:?}");
        }
        assert_eq!(shown[4], 0.0, "B passes as it is");
        assert!(r.position_known(), "learned at rest");
    }
}
