//! Measuring through a tape port (issue 40, item 3), the pure parts: a closed controller
//! takes programs and tells nothing back, so a scan writes its targets as one
//! measurement tape ([`measurement_tape`]: each point approached from its side, then a
//! dwell long enough to settle and grab) and finds each stop from the frames alone
//! ([`StopFinder`]: the board's position read from each frame, still for at least
//! [`StopSpec::min_still_s`], within [`StopSpec::bound_mm`] of the next expected
//! target). The executor that streams the tape while the camera grabs is
//! `runner::tape` (docs/dnc.md).
//!
//! Conventions (*ours*; the manuals fix none of them):
//! * The tape sets G59 to the machine zero (`G10 L2 P6 X0. Y0. Z0.`) and moves in G59, so
//!   its numbers are machine coordinates whatever the operator's G54 holds; G59 is
//!   overwritten (said on the tape's title). Decimal points always, rounded to the
//!   controller's least increment; the expected targets are the rounded numbers.
//! * Dwell `G04 X<s>.` (seconds with a point: independent of parameter 3401#0).
//!
//! Worked example: one point at (10, 20) mm approached from below in X and Y by 0.05 mm,
//! feed 3000, dwell 1.5 s, IS-B:
//! ```text
//! %
//! O9001(GATEWAY MEASUREMENT TAPE - SETS G59 TO MACHINE ZERO)
//! G10L2P6X0.Y0.Z0.
//! G90G17G21G59G01F3000.
//! X9.95Y19.95
//! X10.Y20.
//! G04X1.5
//! M30
//! %
//! ```

/// How a measurement tape is written.
#[derive(Clone, Debug, PartialEq)]
pub struct TapeSpec {
    /// mm/min.
    pub feed_mm_min: f64,
    /// Seconds at each target: the settling and at least two frames' time.
    pub dwell_s: f64,
    /// The controller's least input increment, mm (IS-B 0.001).
    pub increment_mm: f64,
}

/// One target on the tape: where it is approached from and the target, machine mm.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TapeTarget {
    pub approach_mm: [f64; 2],
    pub command_mm: [f64; 2],
}

/// Why a tape could not be written.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum TapeError {
    #[error("{0}")]
    Spec(String),
    #[error("target #{index}: {message}")]
    Target { index: usize, message: String },
}

fn number(v: f64, decimals: usize) -> Option<String> {
    let t = protocol::nc::format_number(v, decimals)?;
    let t = if t.contains('.') {
        t.trim_end_matches('0').to_string()
    } else {
        format!("{t}.")
    };
    Some(if t == "-0." { "0.".into() } else { t })
}

/// The measurement tape of `targets` and the commands the controller will hold at each
/// target (rounded to its increment), machine mm.
pub fn measurement_tape(
    targets: &[TapeTarget],
    spec: &TapeSpec,
) -> Result<(String, Vec<[f64; 2]>), TapeError> {
    let bad = |m: &str| TapeError::Spec(m.into());
    if !(spec.feed_mm_min > 0.0 && spec.feed_mm_min <= 1e5) {
        return Err(bad("the feed must be 0..100000 mm/min"));
    }
    if !(spec.dwell_s >= 0.01 && spec.dwell_s <= 99.0) {
        return Err(bad("the dwell must be 0.01..99 s"));
    }
    if !(spec.increment_mm >= 1e-5 && spec.increment_mm <= 0.01) {
        return Err(bad("the increment must be 0.00001..0.01 mm"));
    }
    let decimals = (-spec.increment_mm.log10()).round() as usize;
    let mut tape = String::from(
        "%\nO9001(GATEWAY MEASUREMENT TAPE - SETS G59 TO MACHINE ZERO)\nG10L2P6X0.Y0.Z0.\n",
    );
    tape.push_str(&format!(
        "G90G17G21G59G01F{}\n",
        number(spec.feed_mm_min, 1).unwrap_or_default()
    ));
    let dwell = number(spec.dwell_s, 3).unwrap_or_default();
    let mut expected = Vec::with_capacity(targets.len());
    // The block last written: an approach point where the tape already is (a sequence
    // of targets, each approached from the one before) is not written again.
    let mut last = String::new();
    for (index, t) in targets.iter().enumerate() {
        let mut xy = |p: [f64; 2], skip_if_there: bool| -> Result<[f64; 2], TapeError> {
            let (Some(x), Some(y)) = (number(p[0], decimals), number(p[1], decimals)) else {
                return Err(TapeError::Target {
                    index,
                    message: "a coordinate is not a finite number".into(),
                });
            };
            if x.len() > 10 || y.len() > 10 {
                return Err(TapeError::Target {
                    index,
                    message: format!("X{x} Y{y} has more digits than the controller takes"),
                });
            }
            let block = format!("X{x}Y{y}\n");
            if !(skip_if_there && block == last) {
                tape.push_str(&block);
            }
            last = block;
            Ok([x.parse().unwrap_or(f64::NAN), y.parse().unwrap_or(f64::NAN)])
        };
        xy(t.approach_mm, true)?;
        expected.push(xy(t.command_mm, false)?);
        tape.push_str(&format!("G04X{dwell}\n"));
    }
    tape.push_str("M30\n%\n");
    Ok((tape, expected))
}

/// The tape's machine time at the programmed feed, without acceleration, s (a lower
/// bound; the wait for a stop that never comes is taken from it).
pub fn machine_time_s(start_mm: [f64; 2], targets: &[TapeTarget], spec: &TapeSpec) -> f64 {
    let mut at = start_mm;
    let mut path = 0.0;
    for t in targets {
        for p in [t.approach_mm, t.command_mm] {
            path += (p[0] - at[0]).hypot(p[1] - at[1]);
            at = p;
        }
    }
    path / spec.feed_mm_min * 60.0 + spec.dwell_s * targets.len() as f64
}

/// How stops are found in the frames.
#[derive(Clone, Debug, PartialEq)]
pub struct StopSpec {
    /// A frame this close (mm) to the first frame of a rest shows the machine still
    /// (the localization's noise is far below: 2 um by default). Judged against the
    /// rest's first frame, not the previous one, so that a slow move seen by a fast
    /// camera (a few um between frames) is never taken for a rest.
    pub still_mm: f64,
    /// A stop lasts at least this long (s): longer than the instant a machine rests
    /// between two blocks, shorter than the dwell (half of it by default).
    pub min_still_s: f64,
    /// A stop is the next target's when the board's position is this close to it (mm):
    /// the largest error the machine may have there (0.2 mm by default).
    pub bound_mm: f64,
}

/// What a frame told.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Seen {
    Moving,
    /// Still, not (yet) a stop at a target.
    Still,
    /// The machine stopped at target `index`; `at` is where the board says it is.
    Stop {
        index: usize,
        at: [f64; 2],
    },
}

/// Why the stops end: what was measured before is kept by the caller.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum StopError {
    #[error("the machine stopped at target #{seen} while target #{expected} was next: target #{expected} was missed (out of order)")]
    OutOfOrder { expected: usize, seen: usize },
    #[error("target #{expected} never stopped (the tape ended, or its time passed)")]
    NeverStopped { expected: usize },
}

/// Finds the stops of a measurement tape in a stream of localized frames (sans-IO: the
/// caller grabs, localizes and passes each frame's time and board position, in board
/// mm, with the expected targets in board mm). The rest the machine is in at the first
/// frame is not a stop: it began before the tape.
#[derive(Clone, Debug)]
pub struct StopFinder {
    spec: StopSpec,
    targets: Vec<[f64; 2]>,
    next: usize,
    /// The first frame of the current rest (or the last moving frame): time and
    /// position.
    anchor: Option<(f64, [f64; 2])>,
    /// Whether this rest was judged.
    judged: bool,
    /// Whether the machine has moved since the first frame: the rest it was in then
    /// began before the tape (it stood there), so it is no stop, even where a later
    /// target is (a cycle starting where the previous tape left the machine).
    moved: bool,
}

fn distance(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

impl StopFinder {
    pub fn new(targets: Vec<[f64; 2]>, spec: StopSpec) -> Self {
        Self {
            spec,
            targets,
            next: 0,
            anchor: None,
            judged: false,
            moved: false,
        }
    }

    /// Targets stopped at so far (in order: `0..measured()`).
    pub fn measured(&self) -> usize {
        self.next
    }

    pub fn done(&self) -> bool {
        self.next == self.targets.len()
    }

    /// One frame at time `t_s` (any clock, increasing) seeing the board at `at`.
    pub fn push(&mut self, t_s: f64, at: [f64; 2]) -> Result<Seen, StopError> {
        let since = match self.anchor {
            Some((since, p)) if distance(p, at) <= self.spec.still_mm => since,
            _ => {
                // Moved: this frame may be the first of a rest.
                self.moved |= self.anchor.is_some();
                self.anchor = Some((t_s, at));
                self.judged = false;
                return Ok(Seen::Moving);
            }
        };
        if !self.moved || self.judged || t_s - since < self.spec.min_still_s {
            return Ok(Seen::Still);
        }
        self.judged = true;
        if let Some(t) = self.targets.get(self.next) {
            if distance(*t, at) <= self.spec.bound_mm {
                let index = self.next;
                self.next += 1;
                return Ok(Seen::Stop { index, at });
            }
        }
        if let Some(seen) = (self.next + 1..self.targets.len())
            .find(|&j| distance(self.targets[j], at) <= self.spec.bound_mm)
        {
            return Err(StopError::OutOfOrder {
                expected: self.next,
                seen,
            });
        }
        // Still elsewhere (a feed hold, the operator's stop): not a target.
        Ok(Seen::Still)
    }

    /// The tape has run (its time and a margin have passed): every target must have
    /// stopped.
    pub fn finish(&self) -> Result<(), StopError> {
        if self.done() {
            Ok(())
        } else {
            Err(StopError::NeverStopped {
                expected: self.next,
            })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec() -> TapeSpec {
        TapeSpec {
            feed_mm_min: 3000.0,
            dwell_s: 1.5,
            increment_mm: 0.001,
        }
    }

    #[test]
    fn the_tape_is_the_worked_example_and_reads_as_a_fanuc_program() {
        let t = TapeTarget {
            approach_mm: [9.95, 19.95],
            command_mm: [10.0, 20.0],
        };
        let (tape, expected) = measurement_tape(&[t], &spec()).unwrap();
        assert_eq!(
            tape,
            "%\nO9001(GATEWAY MEASUREMENT TAPE - SETS G59 TO MACHINE ZERO)\nG10L2P6X0.Y0.Z0.\nG90G17G21G59G01F3000.\nX9.95Y19.95\nX10.Y20.\nG04X1.5\nM30\n%\n"
        );
        assert_eq!(expected, vec![[10.0, 20.0]]);
        // A target approached from where the tape already is: no block to go there.
        let next = TapeTarget {
            approach_mm: [10.0, 20.0],
            command_mm: [11.0, 20.0],
        };
        let (two, _) = measurement_tape(&[t, next], &spec()).unwrap();
        assert_eq!(two.matches("X10.Y20.\n").count(), 1, "{two}");
        assert!(two.contains("G04X1.5\nX11.Y20.\nG04X1.5\n"), "{two}");
        // The controller's interpreter runs it: the target, then a dwell of 1.5 s.
        use protocol::fanuc::{parse_line, Action, Interpreter, Line, Options};
        let mut i = Interpreter::new(Options::default(), [0.0; 3]);
        i.work_offsets[6] = [5.0, 5.0, 0.0];
        let mut actions = Vec::new();
        for (n, l) in tape.lines().enumerate() {
            if let Line::Block(b) = parse_line(l, n + 1).unwrap() {
                actions.extend(i.execute(&b, n + 1, l).unwrap());
            }
        }
        assert!(actions.contains(&Action::Linear {
            to: [10.0, 20.0, 0.0],
            feed: 3000.0
        }));
        assert!(actions.contains(&Action::Dwell { seconds: 1.5 }));
        // Rounded to the increment: the expected target is what the controller holds.
        let t = TapeTarget {
            approach_mm: [1.0, 1.0],
            command_mm: [1.23456, 2.0],
        };
        assert_eq!(
            measurement_tape(&[t], &spec()).unwrap().1,
            vec![[1.235, 2.0]]
        );
        let bad = TapeSpec {
            dwell_s: 0.0,
            ..spec()
        };
        assert!(measurement_tape(&[t], &bad).is_err());
        let path = 2f64.sqrt() + 0.23456f64.hypot(1.0);
        let time = machine_time_s([0.0, 0.0], &[t], &spec());
        assert!((time - (path / 50.0 + 1.5)).abs() < 1e-9, "{time}");
    }

    fn finder() -> StopFinder {
        StopFinder::new(
            vec![[10.0, 10.0], [20.0, 10.0], [30.0, 10.0]],
            StopSpec {
                still_mm: 0.002,
                min_still_s: 0.5,
                bound_mm: 0.2,
            },
        )
    }

    /// A camera at 100 frames a second sees a slow final approach (1 um between frames,
    /// 6 mm/min) as a series of nearly equal positions: it is a move, not a rest, until
    /// the machine really stands still at the target.
    #[test]
    fn a_slow_creep_seen_by_a_fast_camera_is_not_a_stop() {
        let mut f = finder();
        let mut t = 0.0;
        let mut seen = Vec::new();
        // From the approach point, 60 um off, creeping to the target in 1 um steps.
        for k in 0..=60 {
            t += 0.01;
            let at = [9.94 + 0.001 * k as f64, 10.0];
            seen.push(f.push(t, at).unwrap());
        }
        assert!(
            !seen.iter().any(|s| matches!(s, Seen::Stop { .. })),
            "{seen:?}"
        );
        // Then the dwell at the target: the stop is there.
        let mut stop = None;
        for _ in 0..100 {
            t += 0.01;
            if let Seen::Stop { at, .. } = f.push(t, [10.0, 10.0]).unwrap() {
                stop = Some(at);
            }
        }
        assert_eq!(stop, Some([10.0, 10.0]));
    }

    #[test]
    fn stops_are_the_dwells_at_the_next_target_not_the_rests_between_blocks() {
        let mut f = finder();
        let mut t = 0.0;
        let mut push = |f: &mut StopFinder, at: [f64; 2], frames: usize| {
            let mut seen = Vec::new();
            for _ in 0..frames {
                t += 0.1;
                seen.push(f.push(t, at).unwrap());
            }
            seen
        };
        // Moving, a rest of two frames at the approach point (0.1 s): not a stop.
        push(&mut f, [5.0, 5.0], 1);
        push(&mut f, [9.0, 9.0], 1);
        assert_eq!(
            push(&mut f, [9.95, 9.95], 2),
            vec![Seen::Moving, Seen::Still]
        );
        // The dwell, 30 um off the target (the machine's error): one stop, once.
        let seen = push(&mut f, [10.03, 9.99], 15);
        let stops: Vec<_> = seen
            .iter()
            .filter(|s| matches!(s, Seen::Stop { .. }))
            .collect();
        assert_eq!(
            stops,
            [&Seen::Stop {
                index: 0,
                at: [10.03, 9.99]
            }]
        );
        push(&mut f, [15.0, 10.0], 1);
        push(&mut f, [20.01, 10.0], 10);
        assert_eq!(f.measured(), 2);
        assert_eq!(f.finish(), Err(StopError::NeverStopped { expected: 2 }));
        push(&mut f, [30.0, 10.0], 10);
        assert!(f.done() && f.finish().is_ok());
    }

    #[test]
    fn a_missed_target_ends_the_stops_keeping_what_was_measured() {
        let mut f = finder();
        let mut t = 0.0;
        f.push(t, [5.0, 5.0]).unwrap();
        for at in [[10.0, 10.0]; 10] {
            t += 0.1;
            f.push(t, at).unwrap();
        }
        assert_eq!(f.measured(), 1);
        // The machine stops at the third target: the second was missed.
        let mut error = None;
        for _ in 0..10 {
            t += 0.1;
            if let Err(e) = f.push(t, [30.0, 10.0]) {
                error = Some(e);
                break;
            }
        }
        let e = error.expect("out of order");
        assert_eq!(
            e,
            StopError::OutOfOrder {
                expected: 1,
                seen: 2
            }
        );
        assert!(e.to_string().contains("target #1 was missed"), "{e}");
        assert_eq!(f.measured(), 1);
        // The rest the machine is in when the frames begin is not a stop, even at a
        // target (the previous tape left it there): the target is reached again.
        let mut h = finder();
        for k in 0..10 {
            assert_eq!(
                h.push(f64::from(k), [20.0, 10.0]).unwrap() == Seen::Moving,
                k == 0
            );
        }
        h.push(10.5, [15.0, 10.0]).unwrap();
        let stops: Vec<Seen> = (11..15)
            .map(|k| h.push(f64::from(k), [10.0, 10.0]).unwrap())
            .filter(|s| matches!(s, Seen::Stop { .. }))
            .collect();
        assert_eq!(
            stops,
            [Seen::Stop {
                index: 0,
                at: [10.0, 10.0]
            }]
        );
        // A stop away from every target (a feed hold) is not one.
        let mut g = finder();
        for k in 0..10 {
            assert!(!matches!(
                g.push(f64::from(k), [50.0, 50.0]).unwrap(),
                Seen::Stop { .. }
            ));
        }
    }
}
