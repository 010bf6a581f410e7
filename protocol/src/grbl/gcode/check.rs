//! Steps 2 and 3 of GRBL's `gc_execute_line`: check a read block against the modal
//! state, in GRBL's order (jog, line number, feed rate, tool length offset, coordinate
//! data, non-modal commands, motion, unused words), and work out everything the block
//! will do. Nothing here changes the interpreter: a refused block leaves it as it was.

use super::error::GcodeError;
use super::read::{group, AxisCommand, BlockWords, NonModal, Values};
use super::state::{Interpreter, Motion, FIRST_ROTARY, MM_PER_INCH};

const MAX_LINE_NUMBER: f64 = 10_000_000.0;

/// A checked block: the read words and every value its execution needs.
pub(super) struct Plan<const N: usize> {
    pub block: BlockWords,
    /// mm/min, or 1/min in inverse time mode.
    pub feed: f64,
    pub spindle_speed: f64,
    pub tool_length_offset: f64,
    /// Offset of the block's coordinate system.
    pub coord_system: [f64; N],
    /// G10: which stored system (0..5) and its new offset.
    pub new_stored: Option<(usize, [f64; N])>,
    /// G92 / G92.1: the new G92 offset.
    pub new_offset: Option<[f64; N]>,
    /// G4: seconds.
    pub dwell: Option<f64>,
    /// Where the axis words point, machine mm.
    pub target: [f64; N],
    pub arc: Option<ArcCentre<N>>,
    /// The motion mode moves this block.
    pub moves: bool,
}

/// G2/G3: where the centre is, from the position, and which way the arc turns.
#[derive(Clone, Copy)]
pub(super) struct ArcCentre<const N: usize> {
    pub offset: [f64; N],
    pub clockwise: bool,
}

/// What the non-modal command of a block stores or waits.
struct NonModalData<const N: usize> {
    new_stored: Option<(usize, [f64; N])>,
    new_offset: Option<[f64; N]>,
    dwell: Option<f64>,
}

impl<const N: usize> Interpreter<N> {
    /// Checks a block in GRBL's order and plans it.
    pub(super) fn plan(&self, mut block: BlockWords, jog: bool) -> Result<Plan<N>, GcodeError> {
        if jog {
            check_jog(&block)?;
        }
        check_line_number(&block.values)?;
        let unit = if block.modal.inches { MM_PER_INCH } else { 1.0 };
        let feed = self.block_feed(&block, unit)?;
        let spindle_speed = block.values.s.unwrap_or(self.spindle_speed);
        let tool_length_offset = self.block_tool_length_offset(&mut block, unit)?;
        let coord_system = self.block_coord_system(&mut block);
        let data = self.non_modal_data(&mut block, unit, tool_length_offset, coord_system)?;
        let offset = data.new_offset.unwrap_or(self.coord_offset);
        let target = self.target(&block, unit, tool_length_offset, coord_system, offset);
        let (arc, moves) = self.check_motion(&mut block, unit, feed, target)?;
        check_unused_words(&block.values)?;
        Ok(Plan {
            block,
            feed,
            spindle_speed,
            tool_length_offset,
            coord_system,
            new_stored: data.new_stored,
            new_offset: data.new_offset,
            dwell: data.dwell,
            target,
            arc,
            moves,
        })
    }

    /// The block's feed: F in the block's units, undefined (0) after leaving G93, or
    /// in G93 the block's own F, which a feed motion must have.
    fn block_feed(&self, block: &BlockWords, unit: f64) -> Result<f64, GcodeError> {
        let f = block.values.f;
        if !block.modal.inverse_time {
            return Ok(match f {
                Some(f) => f * unit,
                None if self.modal.inverse_time => 0.0,
                None => self.feed_rate,
            });
        }
        let feed_motion = !matches!(block.modal.motion, Motion::Rapid | Motion::None);
        if block.axis_command == AxisCommand::MotionMode && feed_motion && f.is_none() {
            return Err(GcodeError::UndefinedFeedRate);
        }
        Ok(f.unwrap_or(0.0))
    }

    /// G43.1 takes Z only (error 37); G49 cancels the offset.
    fn block_tool_length_offset(
        &self,
        block: &mut BlockWords,
        unit: f64,
    ) -> Result<f64, GcodeError> {
        let Some(dynamic) = block.tool_length_change else {
            return Ok(self.tool_length_offset);
        };
        block.modal.tool_length_dynamic = dynamic;
        if !dynamic {
            return Ok(0.0);
        }
        match block.values.xyz {
            [None, None, Some(z), None, None, None] => Ok(z * unit),
            _ => Err(GcodeError::G43DynamicAxisError),
        }
    }

    /// The offset of the coordinate system the block selects (G54..G59) or is in.
    fn block_coord_system(&self, block: &mut BlockWords) -> [f64; N] {
        match block.coord_select {
            Some(cs) => {
                block.modal.coord_select = cs;
                self.stored[cs]
            }
            None => self.coord_system,
        }
    }

    /// Checks the non-modal command and takes the value words it uses (P, L).
    fn non_modal_data(
        &self,
        block: &mut BlockWords,
        unit: f64,
        tlo: f64,
        coord_system: [f64; N],
    ) -> Result<NonModalData<N>, GcodeError> {
        let mut data = NonModalData {
            new_stored: None,
            new_offset: None,
            dwell: None,
        };
        match block.non_modal {
            NonModal::Dwell => {
                data.dwell = Some(block.values.p.take().ok_or(GcodeError::ValueWordMissing)?);
            }
            NonModal::SetCoordData => data.new_stored = Some(self.coord_data(block, unit, tlo)?),
            NonModal::SetCoordOffset => {
                data.new_offset = Some(self.coord_offset_from(block, unit, tlo, coord_system)?);
            }
            NonModal::ResetCoordOffset => data.new_offset = Some([0.0; N]),
            NonModal::AbsoluteOverride
                if !matches!(block.modal.motion, Motion::Rapid | Motion::Linear) =>
            {
                return Err(GcodeError::G53InvalidMotionMode);
            }
            _ => {}
        }
        Ok(data)
    }

    /// G10 L2 (offset given) or L20 (offset such that the position reads the given
    /// value), P0 for the active system, P1..P6 for G54..G59.
    fn coord_data(
        &self,
        block: &mut BlockWords,
        unit: f64,
        tlo: f64,
    ) -> Result<(usize, [f64; N]), GcodeError> {
        let v = &mut block.values;
        if !v.has_axis_words() {
            return Err(GcodeError::NoAxisWords);
        }
        // As GRBL 1.1h's gcode.c: only both missing is an error; a missing P is 0 (the
        // active system), a missing L is 0 (not 2 or 20: unsupported).
        let (p, l) = match (v.p.take(), v.l.take()) {
            (None, None) => return Err(GcodeError::ValueWordMissing),
            (p, l) => (p.unwrap_or(0.0), l.unwrap_or(0.0)),
        };
        let p = p.trunc() as usize;
        if p > 6 {
            return Err(GcodeError::UnsupportedCoordSys);
        }
        let relative_to_position = match l as i64 {
            2 => false,
            20 => true,
            _ => return Err(GcodeError::UnsupportedCommand),
        };
        let index = if p > 0 {
            p - 1
        } else {
            block.modal.coord_select
        };
        let mut data = self.stored[index];
        for (i, x) in axis_values(v, unit) {
            data[i] = if relative_to_position {
                self.position[i] - self.coord_offset[i] - x - z_only(i, tlo)
            } else {
                x
            };
        }
        Ok((index, data))
    }

    /// G92: the offset that makes the current position read the given values.
    fn coord_offset_from(
        &self,
        block: &BlockWords,
        unit: f64,
        tlo: f64,
        coord_system: [f64; N],
    ) -> Result<[f64; N], GcodeError> {
        if !block.values.has_axis_words() {
            return Err(GcodeError::NoAxisWords);
        }
        let mut offset = self.coord_offset;
        for (i, x) in axis_values(&block.values, unit) {
            offset[i] = self.position[i] - coord_system[i] - x - z_only(i, tlo);
        }
        Ok(offset)
    }

    /// Where the axis words of a motion or G28/G30 point, in machine mm (G53: machine
    /// coordinates; G91: from the position; else work coordinates).
    fn target(
        &self,
        block: &BlockWords,
        unit: f64,
        tlo: f64,
        coord_system: [f64; N],
        offset: [f64; N],
    ) -> [f64; N] {
        let mut target = self.position;
        let moves_axes = matches!(
            block.axis_command,
            AxisCommand::MotionMode | AxisCommand::NonModal
        );
        let sets_data = matches!(
            block.non_modal,
            NonModal::SetCoordData | NonModal::SetCoordOffset
        );
        if !moves_axes || sets_data {
            return target;
        }
        for (i, x) in axis_values(&block.values, unit) {
            target[i] = if block.non_modal == NonModal::AbsoluteOverride {
                x
            } else if block.modal.incremental {
                self.position[i] + x
            } else {
                let work = x + coord_system[i] + offset[i];
                // Added only on Z: adding 0.0 elsewhere would turn a -0.0 into 0.0.
                if i == 2 {
                    work + tlo
                } else {
                    work
                }
            };
        }
        target
    }

    /// Checks the motion mode against the block; returns the arc (if any) and whether
    /// the block moves.
    fn check_motion(
        &self,
        block: &mut BlockWords,
        unit: f64,
        feed: f64,
        target: [f64; N],
    ) -> Result<(Option<ArcCentre<N>>, bool), GcodeError> {
        let axis_words = block.values.has_axis_words();
        let motion = block.modal.motion;
        if motion == Motion::None {
            return match axis_words {
                true => Err(GcodeError::AxisWordsExist),
                false => Ok((None, false)),
            };
        }
        if block.axis_command != AxisCommand::MotionMode {
            return Ok((None, false));
        }
        if motion != Motion::Rapid && feed == 0.0 {
            return Err(GcodeError::UndefinedFeedRate);
        }
        match motion {
            Motion::ArcCw | Motion::ArcCcw => {
                let offset = self.arc_offset(block, unit, target)?;
                let clockwise = motion == Motion::ArcCw;
                Ok((Some(ArcCentre { offset, clockwise }), true))
            }
            Motion::Probe(_) => self.check_probe(axis_words, target).map(|()| (None, true)),
            _ => Ok((None, axis_words)),
        }
    }

    /// G2/G3: the centre offset from the R word or the IJK words, taking the words it
    /// uses, as GRBL 1.1h does (gcode.c): with R the I/J/K words stay unused, so a block
    /// with both is error:36; with offsets all of I, J and K are taken (a K in G17 too).
    fn arc_offset(
        &self,
        block: &mut BlockWords,
        unit: f64,
        target: [f64; N],
    ) -> Result<[f64; N], GcodeError> {
        let v = &mut block.values;
        if !v.has_axis_words() {
            return Err(GcodeError::NoAxisWords);
        }
        let axes @ (a0, a1, _) = block.modal.plane.axes();
        if v.xyz[a0].is_none() && v.xyz[a1].is_none() {
            return Err(GcodeError::NoAxisWordsInPlane);
        }
        let chord = (
            target[a0] - self.position[a0],
            target[a1] - self.position[a1],
        );
        let clockwise = block.modal.motion == Motion::ArcCw;
        let (o0, o1) = match v.r.take() {
            Some(r) => arc_offset_from_radius(chord, r * unit, clockwise)?,
            None => {
                let offsets = arc_offset_from_ijk(v, axes, chord, unit);
                v.ijk = [None; 3];
                offsets?
            }
        };
        let mut offset = [0.0; N];
        offset[a0] = o0;
        offset[a1] = o1;
        Ok(offset)
    }

    fn check_probe(&self, axis_words: bool, target: [f64; N]) -> Result<(), GcodeError> {
        if !axis_words {
            return Err(GcodeError::NoAxisWords);
        }
        if target == self.position {
            return Err(GcodeError::InvalidTarget);
        }
        Ok(())
    }
}

/// A jog may only hold units, distance mode and G53, and must have F.
fn check_jog(block: &BlockWords) -> Result<(), GcodeError> {
    // GRBL 1.1h checks the jog's feed first (`$J=G4 P1` is error:22, not 16).
    if block.values.f.is_none() {
        return Err(GcodeError::UndefinedFeedRate);
    }
    let allowed = (1 << group::DISTANCE) | (1 << group::UNITS) | (1 << group::NON_MODAL);
    if block.groups & !allowed != 0
        || !matches!(block.non_modal, NonModal::None | NonModal::AbsoluteOverride)
    {
        return Err(GcodeError::InvalidJogCommand);
    }
    // A spindle speed or a tool in a jog is a word no command uses.
    if block.values.s.is_some() || block.values.t.is_some() {
        return Err(GcodeError::UnusedWords);
    }
    Ok(())
}

fn check_line_number(values: &Values) -> Result<(), GcodeError> {
    match values.n {
        Some(n) if n > MAX_LINE_NUMBER => Err(GcodeError::InvalidLineNumber),
        _ => Ok(()),
    }
}

/// Value words no command used (GRBL's error 36); the commands took theirs.
fn check_unused_words(values: &Values) -> Result<(), GcodeError> {
    let ijk = values.ijk.iter().any(Option::is_some);
    if ijk || values.r.is_some() || values.p.is_some() || values.l.is_some() {
        return Err(GcodeError::UnusedWords);
    }
    Ok(())
}

/// The axis words given: linear axes in mm (G20 inches scaled), rotary axes in
/// degrees as written (grblHAL scales only linear axes by G20).
fn axis_values(values: &Values, unit: f64) -> impl Iterator<Item = (usize, f64)> + '_ {
    values
        .xyz
        .iter()
        .enumerate()
        .filter_map(move |(i, x)| x.map(|x| (i, if i < FIRST_ROTARY { x * unit } else { x })))
}

/// The tool length offset applies to Z only (subtracting 0.0 changes nothing, not even
/// the sign of a zero).
fn z_only(axis: usize, tlo: f64) -> f64 {
    if axis == 2 {
        tlo
    } else {
        0.0
    }
}

/// Centre of an R-form arc (GRBL's formula): on the chord's perpendicular bisector, on
/// the side that makes the arc shorter than half a circle, or longer for a negative R.
fn arc_offset_from_radius(
    (x, y): (f64, f64),
    r: f64,
    clockwise: bool,
) -> Result<(f64, f64), GcodeError> {
    if x == 0.0 && y == 0.0 {
        return Err(GcodeError::InvalidTarget);
    }
    let h2 = 4.0 * r * r - x * x - y * y;
    if h2 < 0.0 {
        return Err(GcodeError::ArcRadiusError);
    }
    let mut h = -h2.sqrt() / x.hypot(y);
    if !clockwise {
        h = -h;
    }
    if r < 0.0 {
        h = -h;
    }
    Ok((0.5 * (x - y * h), 0.5 * (y + x * h)))
}

/// Centre of an IJK-form arc; the target must lie on the circle (GRBL's tolerance:
/// 0.005 mm, or else 0.5 mm and 0.1 % of the radius).
fn arc_offset_from_ijk(
    v: &mut Values,
    (a0, a1, _): (usize, usize, usize),
    (x, y): (f64, f64),
    unit: f64,
) -> Result<(f64, f64), GcodeError> {
    if v.ijk[a0].is_none() && v.ijk[a1].is_none() {
        return Err(GcodeError::NoOffsetsInPlane);
    }
    let o0 = v.ijk[a0].take().unwrap_or(0.0) * unit;
    let o1 = v.ijk[a1].take().unwrap_or(0.0) * unit;
    let target_radius = (x - o0).hypot(y - o1);
    let radius = o0.hypot(o1);
    let dr = (target_radius - radius).abs();
    if dr > 0.005 && (dr > 0.5 || dr > 0.001 * radius) {
        return Err(GcodeError::InvalidTarget);
    }
    Ok((o0, o1))
}
