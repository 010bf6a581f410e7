//! Streaming a whole G-code program by character counting, with progress, stop on the
//! first refused line, and an exact account of what was acknowledged when the port
//! fails.

use super::GrblStage;
use crate::error::DriverError;
use crate::program::{StreamError, StreamOptions, StreamReport};
use crate::stage::Stage;
use protocol::grbl::gcode::{words, Interpreter};
use protocol::grbl::response::Response;
use protocol::grbl::status::MachineState;
use protocol::grbl::stream::{ProgramStream, StreamEvent, StreamProgress};
use protocol::grbl::{error_text, Realtime};
use std::collections::HashMap;
use std::time::Duration;
use tokio::time::Instant;

impl GrblStage {
    /// Stream a program by character counting. `progress` is called whenever lines are
    /// acknowledged or known executed.
    pub async fn stream_program(
        &mut self,
        program: &str,
        opts: &StreamOptions,
        progress: &mut (dyn FnMut(StreamProgress) + Send),
    ) -> Result<StreamReport, StreamError> {
        let started = Instant::now();
        let device = self.device();
        let fail = |cause: DriverError,
                    line: Option<usize>,
                    text: Option<String>,
                    progress: StreamProgress| StreamError {
            cause,
            line,
            text,
            progress,
            acknowledged_after: Vec::new(),
        };
        let mut stream = ProgramStream::new(program, self.build.rx_buffer).map_err(|e| {
            fail(
                DriverError::Refused {
                    device: device.clone(),
                    what: format!("line {} (checked before sending)", e.line),
                    code: if matches!(e.error, protocol::grbl::gcode::FilterError::Overflow { .. })
                    {
                        11
                    } else {
                        0
                    },
                    message: e.error.to_string(),
                },
                Some(e.line),
                program.lines().nth(e.line - 1).map(str::to_string),
                StreamProgress::default(),
            )
        })?;
        let total = stream.lines().len();
        let skip = opts.start_line.min(total);
        // Lines to skip are treated as already done: the stream starts after them.
        if skip > 0 {
            let rest: Vec<&str> = program.lines().skip(skip).collect();
            stream = ProgramStream::new(&rest.join("\n"), self.build.rx_buffer).map_err(|e| {
                fail(
                    DriverError::Protocol {
                        device: device.clone(),
                        message: e.to_string(),
                    },
                    Some(e.line + skip),
                    None,
                    StreamProgress::default(),
                )
            })?;
        }
        let offset = skip;
        let abs = |p: StreamProgress| StreamProgress {
            total: p.total + offset,
            sent: p.sent + offset,
            acknowledged: p.acknowledged + offset,
            executed: p.executed + offset,
        };
        if opts.preflight {
            let mut interp = Interpreter::new();
            // Seed with the controller's modal state and position.
            if let Ok(info) = self
                .command(&protocol::grbl::Command::ViewParserState)
                .await
            {
                for r in info {
                    if let Response::ParserState(gc) = r {
                        let seed: String = gc
                            .split_whitespace()
                            .filter(|w| !matches!(*w, "M0" | "M1" | "M2" | "M30"))
                            .collect();
                        let _ = interp.execute(&seed, false);
                    }
                }
            }
            if let Ok(p) = self.position().await {
                interp.position = [
                    p.get(crate::stage::Axis::X).unwrap_or(0.0),
                    p.get(crate::stage::Axis::Y).unwrap_or(0.0),
                    p.get(crate::stage::Axis::Z).unwrap_or(0.0),
                ];
            }
            for (i, l) in stream.lines().iter().enumerate() {
                if l.is_empty() || l.starts_with('$') {
                    continue;
                }
                if let Err(code) = interp.execute(l, false) {
                    return Err(fail(
                        DriverError::Refused {
                            device: device.clone(),
                            what: format!(
                                "line {} (checked before sending; nothing was sent)",
                                i + 1 + offset
                            ),
                            code: code.into(),
                            message: error_text(code).to_string(),
                        },
                        Some(i + 1 + offset),
                        Some(l.clone()),
                        abs(stream.progress()),
                    ));
                }
            }
        }
        // N-numbers of lines, to turn `Ln:` into "executed up to".
        let mut by_number: HashMap<u32, usize> = HashMap::new();
        for (i, l) in stream.lines().iter().enumerate() {
            if let Ok(w) = words(l) {
                if let Some(n) = w.iter().find(|w| w.letter == 'N') {
                    by_number.insert(n.value as u32, i);
                }
            }
        }
        let mut max_in_flight = 0usize;
        let mut min_free_blocks: Option<u16> = None;
        let mut next_poll = Instant::now() + opts.status_interval;
        let mut last_progress = Instant::now();
        let mut acknowledged_after = Vec::new();
        let mut alarm: Option<DriverError> = None;
        loop {
            // Send everything that fits in GRBL's RX buffer.
            while let Some((_, bytes)) = stream.next_to_send() {
                max_in_flight = max_in_flight.max(stream.counter().used());
                if let Err(e) = self.link.write(&bytes).await {
                    return Err(fail(e, None, None, abs(stream.progress())));
                }
            }
            if stream.is_finished() || alarm.is_some() {
                break;
            }
            let deadline = next_poll.min(last_progress + self.opts.motion_timeout);
            let r = match self.link.next(deadline).await {
                Err(e) => return Err(fail(e, None, None, abs(stream.progress()))),
                Ok(r) => r,
            };
            let Some(r) = r else {
                if Instant::now() >= last_progress + self.opts.motion_timeout {
                    let p = abs(stream.progress());
                    return Err(fail(
                        DriverError::Timeout {
                            device: device.clone(),
                            what: format!("an answer to line {}", p.acknowledged + 1),
                            after_ms: self.opts.motion_timeout.as_millis() as u64,
                        },
                        Some(p.acknowledged + 1),
                        None,
                        p,
                    ));
                }
                if let Err(e) = self.link.write(&[Realtime::StatusQuery.byte()]).await {
                    return Err(fail(e, None, None, abs(stream.progress())));
                }
                next_poll = Instant::now() + opts.status_interval;
                continue;
            };
            match stream.on_response(&r) {
                StreamEvent::Acknowledged(i) => {
                    last_progress = Instant::now();
                    if stream.refused().is_some() {
                        acknowledged_after.push(i + 1 + offset);
                    }
                    progress(abs(stream.progress()));
                }
                StreamEvent::Refused { index, .. } => {
                    last_progress = Instant::now();
                    if stream.refused().map(|r| r.0) != Some(index) {
                        acknowledged_after.push(index + 1 + offset);
                    }
                    progress(abs(stream.progress()));
                }
                StreamEvent::Lost(lost) => {
                    self.on_banner();
                    let p = abs(stream.progress());
                    let first = lost.first().map(|i| i + 1 + offset);
                    return Err(fail(
                        DriverError::Protocol {
                            device: device.clone(),
                            message: format!("GRBL reset during the stream; {} line(s) in its buffer were discarded unexecuted", lost.len()),
                        },
                        first,
                        None,
                        p,
                    ));
                }
                StreamEvent::None => match &r {
                    Response::Status(s) => {
                        if let Some(w) = &s.wco {
                            self.last_wco = Some(w.clone());
                        }
                        if let Some((blocks, rx)) = s.buffer {
                            min_free_blocks =
                                Some(min_free_blocks.map_or(blocks, |m| m.min(blocks)));
                            stream.counter_mut().observe_rx_size(rx as usize);
                        }
                        let ack = stream.progress().acknowledged;
                        if let Some(n) = s.line_number {
                            if let Some(&i) = by_number.get(&n) {
                                stream.set_executed(i);
                            }
                        }
                        let planner_empty = s
                            .buffer
                            .is_none_or(|(b, _)| b as usize >= self.build.planner_blocks);
                        if s.state == MachineState::Idle
                            && planner_empty
                            && stream.counter().in_flight() == 0
                        {
                            stream.set_executed(ack);
                        }
                        progress(abs(stream.progress()));
                    }
                    Response::Alarm(n) => {
                        self.note_alarm(*n);
                        alarm = Some(self.alarm_error(*n));
                    }
                    Response::Message(m) => self.note_message(m),
                    _ => {}
                },
            }
        }
        if let Some(mut e) = alarm {
            // Let a "Reset to continue" that follows the alarm be seen.
            if let Ok(Some(Response::Message(m))) = self
                .link
                .next(Instant::now() + Duration::from_millis(50))
                .await
            {
                self.note_message(&m);
                e = self.alarm_error(self.last_alarm.unwrap_or(0));
            }
            let p = abs(stream.progress());
            return Err(StreamError {
                cause: e,
                line: Some(p.acknowledged + 1).filter(|&l| l <= p.sent),
                text: None,
                progress: p,
                acknowledged_after,
            });
        }
        if let Some((index, code)) = stream.refused() {
            let text = stream.lines()[index].clone();
            return Err(StreamError {
                cause: self.refused(&format!("line {}", index + 1 + offset), code),
                line: Some(index + 1 + offset),
                text: Some(text),
                progress: abs(stream.progress()),
                acknowledged_after,
            });
        }
        if opts.wait_until_executed {
            if let Err(e) = self.wait_idle().await {
                return Err(fail(e, None, None, abs(stream.progress())));
            }
            let ack = stream.progress().acknowledged;
            stream.set_executed(ack);
            progress(abs(stream.progress()));
        }
        Ok(StreamReport {
            progress: abs(stream.progress()),
            max_in_flight_bytes: max_in_flight,
            rx_buffer: stream.counter().rx_size(),
            min_free_blocks,
            elapsed: started.elapsed(),
        })
    }
}
