//! Step 4 of GRBL's `gc_execute_line`: carry out a checked block, in GRBL's order
//! (line number, feed, tool, spindle and coolant, dwell, offsets, G28/G30, motion,
//! program flow), changing the state and listing the [`Action`]s for the caller.

use super::arc::arc_points;
use super::check::{ArcCentre, Plan};
use super::read::NonModal;
use super::state::{Action, Interpreter, Modal, Motion, Plane, ProgramFlow, Rate, Spindle};

impl<const N: usize> Interpreter<N> {
    /// Executes a planned block; it cannot fail any more.
    pub(super) fn run(&mut self, mut plan: Plan<N>, jog: bool) -> Vec<Action<N>> {
        let line_number = plan.block.values.n.map(|n| n as u32).filter(|&n| n > 0);
        if jog {
            return self.run_jog(&plan, line_number);
        }
        let mut actions = Vec::new();
        self.set_line_feed_and_tool(&plan);
        self.set_spindle_and_coolant(&mut plan, &mut actions);
        actions.extend(plan.dwell.map(Action::Dwell));
        self.set_offsets(&plan, &mut actions);
        self.run_home(&plan, line_number, &mut actions);
        if plan.moves {
            self.run_motion(&plan, line_number, &mut actions);
        }
        if let Some(flow) = plan.block.program_flow {
            self.run_program_flow(flow, &mut plan.block.modal, &mut actions);
        }
        self.modal = plan.block.modal;
        actions
    }

    /// A jog changes nothing modal, only the planned position.
    fn run_jog(&mut self, plan: &Plan<N>, line_number: Option<u32>) -> Vec<Action<N>> {
        let mut actions = Vec::new();
        if plan.target != self.position {
            actions.push(Action::Move {
                target: plan.target,
                rate: Rate::Feed(plan.feed),
                line_number,
                jog: true,
            });
        }
        self.position = plan.target;
        actions
    }

    fn set_line_feed_and_tool(&mut self, plan: &Plan<N>) {
        let v = &plan.block.values;
        if let Some(n) = v.n {
            self.line_number = n as u32;
        }
        if !plan.block.modal.inverse_time {
            self.feed_rate = plan.feed;
        }
        // GRBL 1.1h sets the tool from every block: a block without T selects tool 0.
        self.tool = v.t.map_or(0, |t| t as u8);
    }

    /// New spindle state, a new speed while the spindle runs, or new coolant: wait for
    /// motion to end, then switch.
    fn set_spindle_and_coolant(&mut self, plan: &mut Plan<N>, actions: &mut Vec<Action<N>>) {
        let block = &mut plan.block;
        let speed_changed = block.values.s.is_some() && plan.spindle_speed != self.spindle_speed;
        let changed = block.spindle.is_some_and(|s| s != self.modal.spindle)
            || (speed_changed && self.modal.spindle != Spindle::Off)
            || block.coolant.is_some_and(|c| c != self.modal.flood);
        self.spindle_speed = plan.spindle_speed;
        if let Some(s) = block.spindle {
            block.modal.spindle = s;
        }
        if let Some(c) = block.coolant {
            block.modal.flood = c;
        }
        if changed {
            actions.extend([Action::Sync, Action::Accessories]);
        }
    }

    /// Tool length offset, coordinate system, stored data and G92 offset; any change
    /// of the work offset waits for motion to end and is reported.
    fn set_offsets(&mut self, plan: &Plan<N>, actions: &mut Vec<Action<N>>) {
        let mut wco_changed = false;
        let block = &plan.block;
        if block.tool_length_change.is_some() && plan.tool_length_offset != self.tool_length_offset
        {
            self.tool_length_offset = plan.tool_length_offset;
            wco_changed = true;
        }
        if block.coord_select.is_some() && plan.coord_system != self.coord_system {
            self.coord_system = plan.coord_system;
            wco_changed = true;
        }
        if let Some((index, data)) = plan.new_stored {
            self.stored[index] = data;
            if index == block.modal.coord_select {
                self.coord_system = data;
                wco_changed = true;
            }
        }
        if let Some(offset) = plan.new_offset.filter(|&o| o != self.coord_offset) {
            self.coord_offset = offset;
            wco_changed = true;
        }
        if wco_changed {
            actions.extend([Action::Sync, Action::WcoChanged]);
        }
    }

    /// G28/G30: go to the stored position; G28.1/G30.1: store the position.
    fn run_home(&mut self, plan: &Plan<N>, line_number: Option<u32>, actions: &mut Vec<Action<N>>) {
        match plan.block.non_modal {
            NonModal::GoHome0 => self.go_home(6, plan, line_number, actions),
            NonModal::GoHome1 => self.go_home(7, plan, line_number, actions),
            NonModal::SetHome0 => self.stored[6] = self.position,
            NonModal::SetHome1 => self.stored[7] = self.position,
            _ => {}
        }
    }

    /// Rapid through the axis words (if any), then to stored position `index`.
    fn go_home(
        &mut self,
        index: usize,
        plan: &Plan<N>,
        line_number: Option<u32>,
        actions: &mut Vec<Action<N>>,
    ) {
        let home = self.stored[index];
        let via = plan.block.values.has_axis_words().then_some(plan.target);
        for target in via.into_iter().chain([home]) {
            actions.push(Action::Move {
                target,
                rate: Rate::Rapid,
                line_number,
                jog: false,
            });
        }
        self.position = home;
    }

    fn run_motion(
        &mut self,
        plan: &Plan<N>,
        line_number: Option<u32>,
        actions: &mut Vec<Action<N>>,
    ) {
        let modal = &plan.block.modal;
        let target = plan.target;
        match (modal.motion, plan.arc) {
            (Motion::ArcCw | Motion::ArcCcw, Some(ArcCentre { offset, clockwise })) => {
                let points = arc_points(
                    self.position,
                    target,
                    offset,
                    modal.plane.axes(),
                    clockwise,
                    self.arc_tolerance,
                );
                let rate = arc_segment_rate(modal, plan.feed, points.len());
                actions.extend(points.into_iter().map(|target| Action::Move {
                    target,
                    rate,
                    line_number,
                    jog: false,
                }));
            }
            (Motion::Probe(digit), _) => actions.push(Action::Probe {
                target,
                feed: plan.feed,
                toward: digit <= 3,
                fail_is_error: digit == 2 || digit == 4,
            }),
            _ => actions.push(Action::Move {
                target,
                rate: self.straight_rate(modal, plan.feed, target),
                line_number,
                jog: false,
            }),
        }
        self.position = target;
    }

    /// G0 at the rapid rate; a feed move at F, or in G93 at F times the length (the
    /// move takes 1/F minutes).
    fn straight_rate(&self, modal: &Modal, feed: f64, target: [f64; N]) -> Rate {
        if modal.motion == Motion::Rapid {
            return Rate::Rapid;
        }
        if !modal.inverse_time {
            return Rate::Feed(feed);
        }
        let length = (0..N)
            .map(|i| (target[i] - self.position[i]).powi(2))
            .sum::<f64>()
            .sqrt();
        Rate::Feed(feed * length)
    }

    /// M0 pauses after motion ends; M2/M30 end the program: back to G1 G17 G90 G94 G54,
    /// spindle and coolant off.
    fn run_program_flow(
        &mut self,
        flow: ProgramFlow,
        modal: &mut Modal,
        actions: &mut Vec<Action<N>>,
    ) {
        actions.push(Action::Sync);
        if flow == ProgramFlow::Paused {
            actions.push(Action::Pause);
        } else {
            modal.motion = Motion::Linear;
            modal.plane = Plane::XY;
            modal.incremental = false;
            modal.inverse_time = false;
            modal.coord_select = 0;
            modal.spindle = Spindle::Off;
            modal.flood = false;
            self.coord_system = self.stored[0];
            actions.push(Action::ProgramEnd);
        }
        modal.program_flow = ProgramFlow::Running;
    }
}

/// Each chord of an arc: at F, or in G93 at F times the number of chords (the whole
/// arc takes 1/F minutes).
fn arc_segment_rate(modal: &Modal, feed: f64, segments: usize) -> Rate {
    if modal.inverse_time {
        Rate::Feed(0.0_f64.max(feed * segments as f64))
    } else {
        Rate::Feed(feed)
    }
}
