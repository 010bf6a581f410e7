//! A Fanuc program drip-fed to a closed controller through its tape port, rewritten with
//! the error map on the way (`gateway dnc`; docs/dnc.md): the program (and the
//! controller's stored subprograms, if any) in, the rewritten tape as an artifact
//! ([`TAPE_ARTIFACT`]), then sent through the drivers' factory (a `dnc` stage: DC1/DC3
//! honoured, NAK and SYN reported) to the port the request or the job names.
//!
//! The rewrite is sans-IO ([`prepare`]); only the sending touches a port.

use crate::command_line::{self, FileArg};
use crate::request::{number, RequestError};
use crate::rewrite::{MAX_COORDINATE_MM, MAX_OUTPUT_BYTES, MAX_PROGRAM_BYTES};
use crate::{Artifact, Outcome};
use drivers::dnc::{DncAxis, DncOptions};
use errormap::MapModel;
use rewrite::fanuc::{rewrite_fanuc, FanucOptions, FanucReport};
use rewrite::{Compensation, Identity as NoCompensation};
use serde::{Deserialize, Serialize};
use std::fmt::Write;
use std::time::Instant;

/// The rewritten tape's artifact.
pub const TAPE_ARTIFACT: &str = "tape.nc";

fn default_program_name() -> String {
    "program.nc".into()
}
fn default_tolerance() -> f64 {
    0.5
}
fn default_max_correction() -> f64 {
    200.0
}
fn default_baud() -> u32 {
    9600
}
fn default_true() -> bool {
    true
}
fn default_increment() -> f64 {
    0.001
}
fn default_block_chars() -> usize {
    128
}

/// A program for a closed controller, rewritten and drip-fed. On the command line its
/// flags are these fields (the program and subprogram files are read into them by the
/// front end; `--no-send` and `--no-block-skip` clear `send` and `block_skip`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[cfg_attr(feature = "cli", derive(clap::Args))]
#[serde(deny_unknown_fields)]
pub struct DncRequest {
    /// The program's text (Fanuc dialect, ISO code): `%`, the main program up to
    /// M30/M02, then its subprograms (`O....` to `M99`), `%`.
    #[schema(format = Binary, max_length = 16777216)]
    #[cfg_attr(feature = "cli", arg(skip))]
    pub program: String,
    /// How messages name the program (its file name).
    #[serde(default = "default_program_name")]
    #[schema(default = default_program_name)]
    #[cfg_attr(feature = "cli", arg(skip = default_program_name()))]
    pub program_name: String,
    /// The subprograms stored in the controller that the program calls (M98), as a
    /// tape of definitions: they are expanded where they run.
    #[serde(default)]
    #[schema(format = Binary)]
    #[cfg_attr(feature = "cli", arg(skip))]
    pub subprograms: Option<String>,
    /// The serial port wired to the controller's tape port (the command line only);
    /// none: the job's `[stage] driver = "dnc"`.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long))]
    pub port: Option<String>,
    /// With `port`: the baud rate set on the controller.
    #[serde(default = "default_baud")]
    #[schema(default = default_baud, minimum = 50, maximum = 921600)]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_baud(), requires = "port"))]
    pub baud: u32,
    /// Whether the tape is sent; when not (`--no-send`, with `--out`), it is only
    /// rewritten and the tape is the artifact.
    #[serde(default = "default_true")]
    #[schema(default = default_true)]
    #[cfg_attr(feature = "cli", arg(long = "no-send", action = clap::ArgAction::SetFalse, requires = "out"))]
    pub send: bool,
    /// Send the program without correction (rewritten with decimal points, subprograms
    /// expanded: the baseline to compare with); no map.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, conflicts_with = "map"))]
    pub uncompensated: bool,
    /// Apply the map as scanned, without its recorded reference.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, requires = "map"))]
    pub no_reference: bool,
    /// Largest distance of the executed path from the compensated path, um.
    #[serde(default = "default_tolerance")]
    #[schema(default = default_tolerance, minimum = 0.01, maximum = 1000.0)]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_tolerance()))]
    pub tolerance_um: f64,
    /// Largest correction accepted at any point, um.
    #[serde(default = "default_max_correction")]
    #[schema(default = default_max_correction, minimum = 0.001, maximum = 100000.0)]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_max_correction()))]
    pub max_correction_um: f64,
    /// Machine position when the program starts, `[x, y]` or `[x, y, z]` mm (else the
    /// first moves must name every compensated axis in G90). Command line: `X,Y[,Z]`.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, value_parser = crate::rewrite::pose_mm))]
    pub start: Option<::std::vec::Vec<f64>>,
    /// The controller's stored work offsets G54, G55, ... (up to six `[x, y, z]`, machine
    /// mm), as on its offset screen: a tape port cannot read them. Command line:
    /// `X,Y,Z[;X,Y,Z...]`.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, value_parser = work_offsets_mm))]
    pub work_offsets: Option<::std::vec::Vec<[f64; 3]>>,
    /// The external work offset (added to every system), mm. Command line: `X,Y,Z`.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long, value_parser = crate::volumetric::xyz_mm))]
    pub external_offset: Option<[f64; 3]>,
    /// Parameter 3401#0 DPI: a dimension without a decimal point is in whole mm/inches
    /// (true) or in least input increments (false, the default).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long))]
    pub calculator_input: bool,
    /// Least input increment, mm (IS-B 0.001, IS-C 0.0001); inches: a tenth of it.
    #[serde(default = "default_increment")]
    #[schema(default = default_increment, minimum = 0.00001, maximum = 0.01)]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_increment()))]
    pub increment_mm: f64,
    /// Whether the panel's block-skip switch is on: blocks starting with `/` are then
    /// left out; off (`--no-block-skip`), they are rewritten as ordinary blocks.
    #[serde(default = "default_true")]
    #[schema(default = default_true)]
    #[cfg_attr(feature = "cli", arg(long = "no-block-skip", action = clap::ArgAction::SetFalse))]
    pub block_skip: bool,
    /// Longest block the controller takes, characters (not found in the public
    /// manuals: 128 by default).
    #[serde(default = "default_block_chars")]
    #[schema(default = default_block_chars, minimum = 16, maximum = 4096)]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_block_chars()))]
    pub max_block_chars: usize,
    /// Pad blocks to an even length (the controller's TV check is on).
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long))]
    pub tv_pad: bool,
    /// The serial port the operator's DNC sender is wired to (the command line only):
    /// the program comes from it, each block rewritten and drip-fed to the controller
    /// as it arrives, instead of from `program`; the gateway answers the sender as a
    /// controller does (DC1, DC3 when its buffer is full, DC1 when it drained; DC3 NAK,
    /// an alarm, on a block it cannot rewrite). Its subprograms must be the stored ones.
    #[serde(default)]
    #[cfg_attr(feature = "cli", arg(long))]
    pub from_port: Option<String>,
    /// With `from_port`: the baud rate its sender is set to.
    #[serde(default = "default_baud")]
    #[schema(default = default_baud, minimum = 50, maximum = 921600)]
    #[cfg_attr(feature = "cli", arg(long, default_value_t = default_baud(), requires = "from_port"))]
    pub from_baud: u32,
}

/// `X,Y,Z[;X,Y,Z...]` (mm): work offsets G54, G55, ... as a command-line value; the
/// count and the bounds are the request's to check.
#[cfg(feature = "cli")]
pub fn work_offsets_mm(text: &str) -> Result<Vec<[f64; 3]>, crate::Error> {
    text.split(';').map(crate::volumetric::xyz_mm).collect()
}

impl DncRequest {
    pub fn new(program: String) -> Self {
        Self {
            program,
            program_name: default_program_name(),
            subprograms: None,
            port: None,
            baud: default_baud(),
            send: true,
            uncompensated: false,
            no_reference: false,
            tolerance_um: default_tolerance(),
            max_correction_um: default_max_correction(),
            start: None,
            work_offsets: None,
            external_offset: None,
            calculator_input: false,
            increment_mm: default_increment(),
            block_skip: true,
            max_block_chars: default_block_chars(),
            tv_pad: false,
            from_port: None,
            from_baud: default_baud(),
        }
    }

    pub fn check(&self) -> Result<(), RequestError> {
        self.options().map(|_| ())
    }

    /// The rewrite's options, every field checked (the field named).
    pub fn options(&self) -> Result<FanucOptions, RequestError> {
        for (field, text) in [
            ("program", Some(&self.program)),
            ("subprograms", self.subprograms.as_ref()),
        ] {
            if let Some(t) = text {
                if t.len() > MAX_PROGRAM_BYTES {
                    return Err(RequestError::new(
                        field,
                        format!(
                            "{} bytes; at most {MAX_PROGRAM_BYTES} are accepted",
                            t.len()
                        ),
                    ));
                }
            }
        }
        if let Some(port) = &self.port {
            if port.is_empty() || port.contains(char::is_whitespace) {
                return Err(RequestError::new(
                    "port",
                    "must be a serial port (no blanks)",
                ));
            }
        }
        if !(50..=921_600).contains(&self.baud) {
            return Err(RequestError::new("baud", "must be 50..=921600"));
        }
        if !(50..=921_600).contains(&self.from_baud) {
            return Err(RequestError::new("from_baud", "must be 50..=921600"));
        }
        if let Some(port) = &self.from_port {
            if port.is_empty() || port.contains(char::is_whitespace) {
                return Err(RequestError::new(
                    "from_port",
                    "must be a serial port (no blanks)",
                ));
            }
            if !self.send {
                return Err(RequestError::new(
                    "from_port",
                    "a live sender's program is drip-fed as it arrives: it cannot be kept without sending",
                ));
            }
        }
        number("tolerance_um", self.tolerance_um, 0.01, 1000.0)?;
        number("max_correction_um", self.max_correction_um, 1e-3, 1e5)?;
        number("increment_mm", self.increment_mm, 1e-5, 0.01)?;
        if !(16..=4096).contains(&self.max_block_chars) {
            return Err(RequestError::new("max_block_chars", "must be 16..=4096"));
        }
        let start = crate::rewrite::start_point(self.start.as_deref())?;
        let mut work_offsets = [[0.0; 3]; 7];
        if let Some(v) = &self.work_offsets {
            if v.len() > 6 {
                return Err(RequestError::new(
                    "work_offsets",
                    format!("G54..G59 are six systems, got {}", v.len()),
                ));
            }
            for (k, o) in v.iter().enumerate() {
                for (a, c) in o.iter().enumerate() {
                    number(
                        &format!("work_offsets[{k}][{a}]"),
                        *c,
                        -MAX_COORDINATE_MM,
                        MAX_COORDINATE_MM,
                    )?;
                }
                work_offsets[k + 1] = *o;
            }
        }
        if let Some(o) = &self.external_offset {
            for (a, c) in o.iter().enumerate() {
                number(
                    &format!("external_offset[{a}]"),
                    *c,
                    -MAX_COORDINATE_MM,
                    MAX_COORDINATE_MM,
                )?;
            }
            work_offsets[0] = *o;
        }
        Ok(FanucOptions {
            program: protocol::fanuc::Options {
                calculator_input: self.calculator_input,
                increment_mm: self.increment_mm,
                increment_inch: self.increment_mm / 10.0,
                block_skip: self.block_skip,
                ..protocol::fanuc::Options::default()
            },
            tolerance_mm: self.tolerance_um / 1000.0,
            max_correction_mm: self.max_correction_um / 1000.0,
            limits: None,
            start,
            work_offsets,
            max_block_chars: self.max_block_chars,
            tv_pad: self.tv_pad,
            max_output_bytes: MAX_OUTPUT_BYTES,
        })
    }
}

impl crate::registry::Checked for DncRequest {
    fn check(&self) -> Result<(), RequestError> {
        DncRequest::check(self)
    }
}

/// The rewrite alone (sans-IO): the tape to send and what the rewrite did. Errors name
/// the program and the block.
pub fn prepare(
    request: &DncRequest,
    compensation: &dyn Compensation,
) -> Result<(String, FanucReport), crate::Error> {
    let options = (request.options()).map_err(|e| crate::Error::Input(e.to_string()))?;
    rewrite_fanuc(
        &request.program,
        request.subprograms.as_deref(),
        compensation,
        options,
    )
    // What the controller would not run as written: refused, nothing sent.
    .map_err(|e| crate::Error::Refused(format!("{}: {e}", request.program_name)))
}

/// A program drip-fed (or only rewritten): what went in and out, what the rewrite did,
/// how much of the tape reached the controller.
#[derive(Debug, Clone, Serialize, Deserialize, utoipa::ToSchema)]
pub struct DncResult {
    /// The program as the request names it (a live sender: its port).
    pub input: String,
    /// The tape's artifact ([`TAPE_ARTIFACT`]; a live sender: the controller's port).
    pub output: String,
    /// The compensation in one line.
    pub compensation: String,
    /// The chord tolerance, um.
    pub tolerance_um: f64,
    /// The tape port it was sent to (null: not sent).
    pub port: Option<String>,
    /// Tape lines the controller took.
    pub sent_lines: usize,
    /// A live sender: lines it sent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lines_received: Option<usize>,
    /// Lines of the rewritten tape (absent for a live sender).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tape_lines: Option<usize>,
    /// Its size, bytes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tape_bytes: Option<usize>,
    /// What the rewrite did (absent: a live sender's relay that did not end).
    #[serde(flatten)]
    #[schema(inline)]
    pub report: Option<DncReport>,
    /// How long it took, s (absent: it did not end well).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub elapsed_s: Option<f64>,
}

/// What the Fanuc rewrite did.
#[derive(Debug, Clone, Serialize, Deserialize, utoipa::ToSchema)]
pub struct DncReport {
    /// The main program's `O` number, when it has one.
    pub program_number: Option<u32>,
    /// Blocks read and written.
    pub blocks_in: usize,
    pub blocks_out: usize,
    /// Moves whose commands were corrected.
    pub moves_compensated: usize,
    /// Blocks added by splitting moves and turning arcs into chords.
    pub segments_added: usize,
    /// Subprogram runs written out where they run (M98).
    pub calls_expanded: usize,
    /// Blocks skipped by the block skip (`/`).
    pub skipped_blocks: usize,
    /// Largest |command - nominal| over the compensated axes, um.
    pub largest_correction_um: f64,
    /// Line of that largest correction.
    pub largest_correction_line: usize,
    /// What is worth telling that did not stop the rewrite, by line.
    #[schema(inline)]
    pub notes: Vec<crate::rewrite::LineNote>,
}

impl DncReport {
    fn of(r: &FanucReport) -> Self {
        Self {
            program_number: r.program_number,
            blocks_in: r.blocks_in,
            blocks_out: r.blocks_out,
            moves_compensated: r.moves_compensated,
            segments_added: r.segments_added,
            calls_expanded: r.calls_expanded,
            skipped_blocks: r.skipped_blocks,
            largest_correction_um: r.largest_correction_um,
            largest_correction_line: r.largest_correction_line,
            notes: r.notes.iter().map(crate::rewrite::LineNote::of).collect(),
        }
    }
}

/// Where the tape goes: the request's port, else the job's `dnc` stage.
fn link(
    request: &DncRequest,
    cx: &mut dyn crate::Context,
) -> Result<drivers::StageLink, crate::Error> {
    if let Some(port) = &request.port {
        // The travel is the job's business; a program only needs the port.
        let axis = |axis| DncAxis {
            axis,
            min_mm: -MAX_COORDINATE_MM,
            max_mm: MAX_COORDINATE_MM,
            max_feed_mm_min: 1e6,
        };
        return Ok(drivers::StageLink::Dnc {
            port: port.clone(),
            baud: request.baud,
            options: DncOptions::default(),
            axes: vec![axis(drivers::Axis::X), axis(drivers::Axis::Y)],
        });
    }
    let job = cx.job().map_err(|e| {
        crate::Error::Input(format!(
            "no tape port: give the port (--port) or a job whose [stage] driver = \"dnc\" ({e})"
        ))
    })?;
    match &job.stage {
        job::StageSpec::Dnc(spec) => Ok(devices::dnc_link(spec)),
        _ => Err(crate::Error::Input(format!(
            "{}: the stage is not a tape port ([stage] driver = \"dnc\"); give the port (--port)",
            job.source
        ))),
    }
}

/// The rewritten tape's room between the sender and the controller, lines: DC3 to the
/// sender when fewer than a quarter are free, DC1 when three quarters are.
pub const LIVE_BUFFER_LINES: usize = 256;

/// A live sender's program (`from_port`): each line rewritten as it arrives
/// (`rewrite::fanuc::FanucStream`) and drip-fed to the controller while the sender still
/// sends, flow control both ways (drivers' `DncReceiver` and `DncSender::send_live`).
async fn run_live(
    request: &DncRequest,
    from_port: &str,
    compensation: &dyn Compensation,
    cx: &mut dyn crate::Context,
) -> Outcome<DncResult> {
    let started = Instant::now();
    let options = match request.options() {
        Ok(o) => o,
        Err(e) => return Outcome::failed(crate::Error::Input(e.to_string())),
    };
    let link = match link(request, cx) {
        Ok(l) => l,
        Err(e) => return Outcome::failed(e),
    };
    let drivers::StageLink::Dnc {
        port,
        baud,
        options: dnc_options,
        ..
    } = &link
    else {
        return Outcome::failed("the controller's link is not a tape port");
    };
    let mut stream = match rewrite::fanuc::FanucStream::new(
        request.subprograms.as_deref(),
        compensation,
        &options,
    ) {
        Ok(s) => s,
        Err(e) => return Outcome::failed(crate::Error::Refused(format!("subprograms: {e}"))),
    };
    let mut result = DncResult {
        input: format!("the DNC sender on {from_port}"),
        output: link.to_string(),
        compensation: compensation.describe(),
        tolerance_um: request.tolerance_um,
        port: Some(link.to_string()),
        sent_lines: 0,
        lines_received: Some(0),
        tape_lines: None,
        tape_bytes: None,
        report: None,
        elapsed_s: None,
    };
    let stop = cx.stop();
    let relayed = stop
        .unless(async {
            let device = |e: drivers::DriverError| crate::Error::Device(e.to_string());
            let mut receiver = drivers::dnc::DncReceiver::open(from_port, request.from_baud)
                .await
                .map_err(device)?;
            let mut sender = drivers::dnc::DncSender::open(port, *baud, dnc_options.clone())
                .await
                .map_err(|e| crate::Error::Device(format!("opening the tape port: {e}")))?;
            let (tx, mut rx) = tokio::sync::mpsc::channel::<String>(LIVE_BUFFER_LINES);
            // (The receiver's callback answers a `String`: the drivers' signature.)
            let mut on_line = |line: &str| -> Result<Vec<String>, String> {
                stream
                    .push_line(line)
                    .map(|text| text.lines().map(str::to_string).collect())
                    .map_err(|e| format!("the sender's tape: {e}"))
            };
            let receiving = async {
                let r = receiver
                    .receive(
                        &tx,
                        LIVE_BUFFER_LINES / 4,
                        LIVE_BUFFER_LINES * 3 / 4,
                        &mut on_line,
                    )
                    .await;
                drop(tx);
                r
            };
            let mut going_on = |_: &drivers::dnc::TapeProgress| drivers::dnc::Flow::Continue;
            let sending = sender.send_live(&mut rx, &mut going_on);
            let (received, sent) = tokio::join!(receiving, sending);
            // The sender's refusal first: it is why the controller's tape ended short.
            let received = received.map_err(device)?;
            let sent = sent.map_err(|e| crate::Error::Device(e.to_string()))?;
            Ok::<_, crate::Error>((received, sent.sent))
        })
        .await;
    match relayed {
        None => {
            let mut o = Outcome::failed(
                "stopped while relaying: the controller keeps what it read; press RESET on its panel",
            );
            o.end = crate::End::Cancelled;
            o.result = Some(result);
            o
        }
        Some(Err(e)) => {
            let mut o = Outcome::failed(e);
            o.result = Some(result);
            o
        }
        Some(Ok((received, sent))) => {
            result.lines_received = Some(received);
            result.sent_lines = sent;
            result.report = Some(DncReport::of(&stream.finish()));
            succeeded(result, started)
        }
    }
}

/// Rewrites and sends. Progress counts the tape's lines as they are written.
pub async fn run(
    request: &DncRequest,
    compensation: &dyn Compensation,
    cx: &mut dyn crate::Context,
) -> Outcome<DncResult> {
    if let Some(from) = &request.from_port {
        return run_live(request, from, compensation, cx).await;
    }
    let started = Instant::now();
    let (tape, report) = match prepare(request, compensation) {
        Ok(t) => t,
        Err(e) => return Outcome::failed(e),
    };
    let lines = tape.lines().count();
    let mut result = DncResult {
        input: request.program_name.clone(),
        output: TAPE_ARTIFACT.into(),
        compensation: compensation.describe(),
        tolerance_um: request.tolerance_um,
        port: None,
        sent_lines: 0,
        lines_received: None,
        tape_lines: Some(lines),
        tape_bytes: Some(tape.len()),
        report: Some(DncReport::of(&report)),
        elapsed_s: None,
    };
    if let Err(e) = cx.sink().artifact(Artifact {
        name: TAPE_ARTIFACT.into(),
        title: None,
        media_type: "text/x-gcode",
        bytes: tape.clone().into_bytes(),
    }) {
        return Outcome::failed(e);
    }
    if request.send {
        let link = match link(request, cx) {
            Ok(l) => l,
            Err(e) => return Outcome::failed(e),
        };
        result.port = Some(link.to_string());
        let stop = cx.stop();
        let total = lines as u64;
        let sink = cx.sink();
        let sent = stop
            .unless(async {
                let mut stage = drivers::open_stage(&link)
                    .await
                    .map_err(|e| (format!("opening the tape port: {e}"), 0))?;
                // The driver's callback must be Send (the sink is not): it counts, and
                // the sink is told a few times a second.
                let count = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(0));
                let counter = count.clone();
                let mut progress = move |p: protocol::grbl::stream::StreamProgress| {
                    counter.store(p.sent, std::sync::atomic::Ordering::Relaxed);
                };
                let stream_options = drivers::StreamOptions::default();
                let streaming = stage.stream_program(&tape, &stream_options, &mut progress);
                tokio::pin!(streaming);
                let mut tick = tokio::time::interval(std::time::Duration::from_millis(250));
                let done = loop {
                    tokio::select! {
                        r = &mut streaming => break r,
                        _ = tick.tick() => sink.progress(
                            count.load(std::sync::atomic::Ordering::Relaxed) as u64,
                            total,
                        ),
                    }
                };
                done.map(|r| r.progress.sent)
                    .map_err(|e| (e.to_string(), e.progress.sent))
            })
            .await;
        match sent {
            None => {
                let mut o = Outcome::failed(
                    "stopped while sending: the controller keeps what it read; press RESET on its panel",
                );
                o.end = crate::End::Cancelled;
                o.result = Some(result);
                return o;
            }
            Some(Err((e, sent))) => {
                result.sent_lines = sent;
                let mut o = Outcome::failed(e);
                o.result = Some(result);
                return o;
            }
            Some(Ok(sent)) => result.sent_lines = sent,
        }
    }
    succeeded(result, started)
}

/// A run that ended well, from a file or a live sender: its time and the plant's metrics.
fn succeeded(mut result: DncResult, started: std::time::Instant) -> Outcome<DncResult> {
    result.elapsed_s = Some(started.elapsed().as_secs_f64());
    let mut metrics = serde_json::Map::new();
    if let Some(r) = &result.report {
        metrics.insert("moves_compensated".into(), r.moves_compensated.into());
        metrics.insert("segments_added".into(), r.segments_added.into());
        metrics.insert(
            "largest_correction_um".into(),
            r.largest_correction_um.into(),
        );
    }
    metrics.insert("sent_lines".into(), result.sent_lines.into());
    Outcome::succeeded(result, metrics)
}

/// The outcome as text.
pub fn summary(r: &DncResult) -> String {
    let mut t = String::new();
    let _ = writeln!(t, "{} -> {} with {}", r.input, r.output, r.compensation);
    let or_dash = |n: Option<usize>| n.map_or("-".to_string(), |n| n.to_string());
    if let Some(f) = &r.report {
        let _ = writeln!(
            t,
            "{} blocks in, {} out ({} tape lines, {} bytes): {} moves rewritten, {} segments added, {} subprogram runs expanded, {} blocks skipped; largest correction {:.2} um (line {}); tolerance {} um",
            f.blocks_in,
            f.blocks_out,
            or_dash(r.tape_lines),
            or_dash(r.tape_bytes),
            f.moves_compensated,
            f.segments_added,
            f.calls_expanded,
            f.skipped_blocks,
            f.largest_correction_um,
            f.largest_correction_line,
            r.tolerance_um,
        );
    }
    if let Some(port) = &r.port {
        let _ = writeln!(
            t,
            "sent {} of {} lines to the {port}",
            r.sent_lines,
            or_dash(r.tape_lines.or(r.lines_received))
        );
    }
    for n in r.report.iter().flat_map(|f| &f.notes) {
        let _ = writeln!(t, "line {}: {}", n.line, n.note);
    }
    t
}

/// [`run`] as a registered kind: the map (under its current reference) unless
/// `uncompensated`; refused when the map was measured on another machine.
pub struct Dnc;

impl crate::registry::Procedure for Dnc {
    const KIND: &'static str = "dnc";
    const TITLE: &'static str =
        "Drip-feed a Fanuc program to a closed controller through its tape port, rewritten with the error map";
    const COMMAND: &'static str = "dnc";
    const LABEL: &'static str = "Program to a closed controller (DNC)";
    const HELP: &'static str = "Rewrites a Fanuc program with the active error map and drip-feeds it to the machine's tape port (DNC). Select DNC mode and press CYCLE START on the controller when asked.";
    const USES: crate::registry::Uses = crate::registry::Uses {
        map: crate::registry::MapUse::WhenAsked,
        ..crate::registry::Uses::NOTHING
    };
    type Request = DncRequest;
    type Result = DncResult;
    const FILES: &'static [FileArg] = &[
        FileArg::positional(
            "input",
            "The program (Fanuc dialect, ISO code; its subprograms after M30); none with `--from-port` (the program comes from a DNC sender).",
            |path, plan| plan.text(path, "program", Some("program_name"), crate::rewrite::read_program),
        )
        .required_unless(&["from_port"]),
        FileArg::flag(
            "map",
            "The error map (a version file written by `gateway map`).",
            command_line::map,
        )
        .required_unless(&["uncompensated"]),
        FileArg::flag(
            "config",
            "The job of the machine: its `[stage] driver = \"dnc\"` names the tape port, and the map is refused unless it was measured on that machine.",
            command_line::job,
        ),
        FileArg::flag(
            "subprograms",
            "The subprograms stored in the controller that the program calls (M98).",
            |path, plan| plan.text(path, "subprograms", None, crate::rewrite::read_program),
        ),
        FileArg::flag(
            "out",
            "Write the rewritten tape here (never over an input; not with `--from-port`).",
            |path, plan| {
                plan.artifacts.push((TAPE_ARTIFACT.into(), path.to_path_buf()));
                Ok(())
            },
        )
        .conflicts(&["from_port"]),
    ];
    const STEPS: &'static str = "tape lines";

    fn uses_map(request: &DncRequest) -> bool {
        !request.uncompensated
    }

    async fn run(request: DncRequest, cx: &mut dyn crate::Context) -> Outcome<DncResult> {
        if request.uncompensated {
            return run(&request, &NoCompensation, cx).await;
        }
        let (map, reference) =
            crate::or_fail!(crate::reference::active_map(cx, request.no_reference).await);
        let applied = match crate::reference::apply(map, &reference, cx.now()) {
            Ok(a) => a,
            Err(e) => return Outcome::failed(e),
        };
        let model: MapModel = applied.model;
        run(&request, &model, cx).await
    }

    fn summary(result: &DncResult) -> String {
        summary(result)
    }

    const COMMAND_LINE_ONLY: &'static [&'static str] = &["port", "from_port"];

    /// The service sends to the tape port of its machine's job: a port named by a
    /// request from the network is refused.
    fn admit(request: &DncRequest, _facts: &crate::registry::Facts) -> Result<(), RequestError> {
        if request.from_port.is_some() {
            return Err(RequestError::new(
                "from_port",
                "a DNC sender's port is given on the command line of the box it is wired to (gateway dnc --from-port PORT)",
            ));
        }
        if request.port.is_some() {
            return Err(RequestError::new(
                "port",
                "the service sends to the tape port of its machine's job ([stage] driver = \"dnc\"); a port of its own is given on the command line of the box it is on (gateway dnc PROGRAM --port PORT)",
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bounds_are_named_and_the_rewrite_is_sans_io() {
        let mut r = DncRequest::new("%\nG90G00X1.Y1.\nM30\n%\n".into());
        r.baud = 0;
        assert_eq!(r.check().unwrap_err().field, "baud");
        r.baud = 9600;
        r.work_offsets = Some(vec![[0.0; 3]; 7]);
        assert_eq!(r.check().unwrap_err().field, "work_offsets");
        r.work_offsets = Some(vec![[10.0, 20.0, 0.0]]);
        r.increment_mm = 1.0;
        assert_eq!(r.check().unwrap_err().field, "increment_mm");
        r.increment_mm = 0.001;
        r.port = Some("a b".into());
        assert_eq!(r.check().unwrap_err().field, "port");
        r.port = Some("/dev/ttyUSB0".into());
        let facts = crate::registry::Facts::default();
        use crate::registry::Procedure;
        assert_eq!(Dnc::admit(&r, &facts).unwrap_err().field, "port");
        r.program = "%\nG54G90G00X1.Y1.\nM30\n%\n".into();
        let (tape, report) = prepare(&r, &NoCompensation).unwrap();
        // G54 is 10, 20: the controller adds it, the tape keeps the program's numbers.
        assert!(tape.contains("G54G90G00X1.Y1.\n"), "{tape}");
        assert_eq!(report.moves_compensated, 1);
        r.program = "%\nG90G00X1.Y1.\nG41X2.\n%\n".into();
        let e = prepare(&r, &NoCompensation).unwrap_err();
        assert!(matches!(e, crate::Error::Refused(_)), "{e:?}");
        let e = e.to_string();
        assert!(e.starts_with("program.nc: block 3 `G41X2.`"), "{e}");
    }
}
