//! `gateway`: the command line of the compensation gateway.

use clap::{Parser, Subcommand};
use devices::open_devices_async;

use job::Job;
use procedure::request::CompensateRequest;
use protocol::Board;
use serde_json::{json, Value};
use std::path::PathBuf;
use std::process::ExitCode;
use vision::localize::{LocalizeSettings, Method, PixelAxes};

mod export;
mod front;
mod iso230;
mod layout;
mod proxy;
mod rewrite;
mod rotary;
mod scan;
mod serve;
mod verify;
mod volumetric;

#[derive(Parser)]
#[command(
    name = "gateway",
    version,
    about = "Camera + calibration board compensation gateway for X-Y stages and CNC machines"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Run the compensation job on the embedded default: a simulated C5 stage, camera and
    /// certified board, all in-process. Reports the error against the truth.
    Demo {
        /// Print one JSON object instead of the table.
        #[arg(long)]
        json: bool,
        /// Localization method: fit (default) or four-point (the patent's formula).
        #[arg(long)]
        method: Option<String>,
        /// Stage backend: `sim` (in-process) or `grbl` (the GRBL emulator on a real
        /// pseudo-terminal, driven by the GRBL serial driver); `modbus` (the Modbus
        /// drive emulator); `canopen` (CiA 402 drive emulator behind an SLCAN adapter
        /// on a real pseudo-terminal, driven by the CANopen driver).
        #[arg(long, default_value = "sim")]
        stage: String,
        /// With `--stage modbus`: `tcp` (drive emulator on a loopback port) or `rtu`
        /// (on a real pseudo-terminal).
        #[arg(long, default_value = "tcp")]
        transport: String,
        /// Camera link: `sim` (in-process) or `gige` (the GigE Vision emulator on a
        /// loopback UDP port, rendering the same machine, read by the GigE driver).
        #[arg(long, default_value = "sim")]
        camera: String,
        /// Only the first N targets.
        #[arg(long)]
        targets: Option<u64>,
    },
    /// Run the compensation job described by a configuration file.
    Compensate {
        #[arg(long)]
        config: PathBuf,
        #[arg(long)]
        json: bool,
        #[arg(long)]
        method: Option<String>,
        /// Only the first N targets.
        #[arg(long)]
        targets: Option<u64>,
    },
    /// Scan the machine into an error map: a grid over the travel and dense lines along
    /// each axis, every point approached from both sides, `--passes` times. Written as a
    /// new version OUT/NAME.vN.json (never over an older one); a stopped scan resumes
    /// from its journal OUT/NAME.scan.jsonl.
    Map(scan::MapArgs),
    /// Rewrite a G-code program so that every move lands where it was programmed: moves
    /// split against the tolerance, arcs as chords, each point replaced by the command
    /// the error map gives for it. The controller's dialect is GRBL 1.1: what it would
    /// refuse is refused here first, naming the line.
    Rewrite {
        /// The program to rewrite (never overwritten).
        input: PathBuf,
        /// The error map (a version file written by `gateway map`).
        #[arg(long)]
        map: Option<PathBuf>,
        /// With --map: the job of the machine the program is for; the map is refused
        /// unless it was measured on that machine, controller, board and camera.
        #[arg(long, requires = "map")]
        config: Option<PathBuf>,
        /// A volumetric model file (`gateway volumetric identify`): X, Y and Z corrected.
        #[arg(long)]
        volumetric: Option<PathBuf>,
        /// The location errors of an A/C tilting table (`gateway rotary identify` or
        /// `measure`): a 5-axis program (X Y Z A C) rewritten so the tool tip and
        /// direction land where programmed (the same rewrite as `gateway rotary rewrite`).
        #[arg(long)]
        rotary: Option<PathBuf>,
        /// With --rotary: the machine constants (JSON), default the built-in ones.
        #[arg(long, requires = "rotary")]
        machine: Option<PathBuf>,
        #[arg(long)]
        out: PathBuf,
        /// Largest distance of the executed path from the compensated path, um.
        #[arg(long, default_value_t = 0.5)]
        tolerance_um: f64,
        /// Largest correction accepted at any point, um.
        #[arg(long, default_value_t = 200.0)]
        max_correction_um: f64,
        /// The controller's `$#` reply saved to a file: its G54..G59 offsets.
        #[arg(long)]
        offsets: Option<PathBuf>,
        /// Machine position when the program starts, "X,Y[,Z]" mm (else the first
        /// moves must name every compensated axis).
        #[arg(long)]
        start: Option<String>,
        /// Soft limits, "XMIN:XMAX,YMIN:YMAX[,ZMIN:ZMAX]" machine mm.
        #[arg(long)]
        limits: Option<String>,
        #[arg(long)]
        json: bool,
    },
    /// The A/C tilting rotary table (source B): identify its eight location errors.
    Rotary {
        #[command(subcommand)]
        cmd: rotary::RotaryCmd,
    },
    /// Run the gateway as a service: machines, job queues, the HTTP/WebSocket API and
    /// the web page, as configured in BOX.toml. SIGTERM/SIGINT stop it cleanly.
    Serve {
        /// The box's configuration (see config/box/demo.toml).
        #[arg(long)]
        config: std::path::PathBuf,
    },
    /// Cutting layouts for a multi-tool conveyor cutter (Source C).
    Layout {
        #[command(subcommand)]
        cmd: layout::LayoutCmd,
    },
    /// The live pass-through: a pseudo-terminal that answers as a GRBL 1.1 controller to
    /// the G-code sender you already use (UGS, CNCjs, bCNC), rewriting every line and
    /// streaming it to the GRBL controller: with an error map (`--config JOB --map MAP`,
    /// the job's controller) or for a rotary table's location errors (`--rotary ERRORS
    /// --controller PORT`, X Y Z A C on a grblHAL six-axis build). Status reports show
    /// the programmed position. Ctrl-C stops.
    Proxy(proxy::ProxyArgs),
    /// ISO 230-2 positioning test of one axis (A, B, R, E, M), or `evaluate FILE`.
    Iso230(iso230::Iso230Args),
    /// The 21-error volumetric model of a 3-axis machine: identify, eval, contributions,
    /// simulate-campaign, export-isg.
    Volumetric {
        #[command(subcommand)]
        cmd: volumetric::VolumetricCmd,
    },
    /// Check the error map with the camera: home, re-reference the map at its reference
    /// point (each homing moves the zero by a few um), then move to random points with
    /// the map's command and measure where the camera really is. `--spot-check`: a few
    /// points; exit code 2 when any point is off by more than `--drift-threshold-um` (re-scan).
    Verify(verify::VerifyArgs),
    /// Write the map as a controller's own compensation table: `linuxcnc` (a COMP_FILE
    /// per joint, nominal/forward/reverse, at most 256 entries), `beckhoff` (a TwinCAT
    /// CNC plane compensation list per axis over X and Y) or `csv` (the model on the
    /// map's grid). Each says what the format cannot hold and refuses a table further
    /// from the map than the tolerance.
    Export(export::ExportArgs),
    /// Localize one image of the board: the board coordinate under the image centre.
    Localize {
        /// PNG file, 8- or 16-bit greyscale.
        image: PathBuf,
        /// Board file (TOML).
        #[arg(long)]
        board: PathBuf,
        /// Expected board coordinate at the image centre, "X,Y" in mm.
        #[arg(long)]
        near: String,
        #[arg(long, default_value_t = LocalizeSettings::default().method.to_string())]
        method: String,
        /// Nominal scale; the measured scale must agree within 10 %.
        #[arg(long)]
        um_per_px: Option<f64>,
        /// Board directions of the image +x and +y axes.
        #[arg(long, default_value = "+x,-y")]
        pixel_axes: String,
        /// How far the true position may be from --near, mm.
        #[arg(long, default_value_t = LocalizeSettings::default().hint_tolerance_mm)]
        hint_tolerance_mm: f64,
        /// Refuse when the fit's RMS residual exceeds this, um.
        #[arg(long, default_value_t = LocalizeSettings::default().max_residual_um)]
        max_residual_um: f64,
        /// Fewest identified on-board points accepted.
        #[arg(long, default_value_t = LocalizeSettings::default().min_points)]
        min_points: usize,
        #[arg(long)]
        json: bool,
    },
}

fn parse_method(s: &str) -> anyhow::Result<Method> {
    s.parse()
        .map_err(|e| anyhow::anyhow!("--method `{s}`: {e}"))
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let json_mode = match &cli.cmd {
        Cmd::Demo { json, .. }
        | Cmd::Compensate { json, .. }
        | Cmd::Rewrite { json, .. }
        | Cmd::Localize { json, .. } => *json,
        Cmd::Proxy(a) => a.json,
        Cmd::Verify(a) => a.json,
        Cmd::Map(a) => a.json,
        Cmd::Export(a) => a.json,
        Cmd::Rotary { cmd } => cmd.json(),
        Cmd::Iso230(a) => a.json(),
        Cmd::Volumetric { cmd } => cmd.json(),
        Cmd::Layout { cmd } => cmd.json(),
        Cmd::Serve { .. } => false,
    };
    match run(cli) {
        Ok(code) => code,
        Err(e) => {
            let msg = format!("{e:#}");
            if json_mode {
                let _ = front::emit(&format!("{}\n", json!({ "error": msg })));
            }
            eprintln!("error: {msg}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> anyhow::Result<ExitCode> {
    match cli.cmd {
        Cmd::Volumetric { cmd } => volumetric::run(cmd),
        Cmd::Demo {
            json,
            method,
            stage,
            transport,
            camera,
            targets,
        } => {
            let job = procedure::demo::demo_job(&stage, &transport, &camera)
                .map_err(|e| anyhow::anyhow!(e.for_cli()))?;
            let request = CompensateRequest {
                targets,
                method: method.as_deref().map(parse_method).transpose()?,
            };
            compensate(job, request, json)
        }
        Cmd::Compensate {
            config,
            json,
            method,
            targets,
        } => {
            let job = Job::load(&config)?;
            let request = CompensateRequest {
                targets,
                method: method.as_deref().map(parse_method).transpose()?,
            };
            compensate(job, request, json)
        }
        Cmd::Map(a) => scan::map(a),
        Cmd::Rewrite {
            input,
            map,
            config: _,
            volumetric,
            rotary: Some(errors),
            machine,
            out,
            tolerance_um,
            max_correction_um,
            offsets,
            start,
            limits,
            json,
        } => {
            // The 5-axis rewrite has its own program rules (absolute mm, no arcs); the
            // 3-axis options do not apply to it.
            let other = [
                (map.is_some(), "--map"),
                (volumetric.is_some(), "--volumetric"),
                (offsets.is_some(), "--offsets"),
                (start.is_some(), "--start"),
                (limits.is_some(), "--limits"),
                (max_correction_um != 200.0, "--max-correction-um"),
            ];
            if let Some((_, flag)) = other.iter().find(|(given, _)| *given) {
                anyhow::bail!(
                    "--rotary rewrites a 5-axis program on its own; {flag} does not apply to it"
                );
            }
            rotary::run(rotary::RotaryCmd::Rewrite {
                input,
                errors,
                out,
                machine,
                tolerance_um,
                json,
            })
        }
        Cmd::Rewrite {
            input,
            map,
            config,
            volumetric,
            rotary: None,
            machine: _,
            out,
            tolerance_um,
            max_correction_um,
            offsets,
            start,
            limits,
            json,
        } => rewrite::rewrite(rewrite::RewriteArgs {
            input,
            out,
            map,
            config,
            volumetric,
            tolerance_um,
            max_correction_um,
            offsets,
            start,
            limits,
            json,
        }),
        Cmd::Layout { cmd } => layout::run(cmd),
        Cmd::Serve { config } => serve::serve(&config),
        Cmd::Proxy(a) => proxy::proxy(a),
        Cmd::Rotary { cmd } => rotary::run(cmd),
        Cmd::Iso230(a) => iso230::dispatch(a),
        Cmd::Verify(a) => verify::verify(a),
        Cmd::Export(a) => export::export(a),
        Cmd::Localize {
            image,
            board,
            near,
            method,
            um_per_px,
            pixel_axes,
            hint_tolerance_mm,
            max_residual_um,
            min_points,
            json,
        } => {
            let board = Board::load(&board)?;
            let img = vision::image_io::load_png(&image)?;
            let request = procedure::localize::LocalizeRequest {
                near: front::parse_xy(&near)?,
                method: parse_method(&method)?,
                um_per_px,
                pixel_axes: pixel_axes
                    .parse::<PixelAxes>()
                    .map_err(|e| anyhow::anyhow!("--pixel-axes `{pixel_axes}`: {e}"))?,
                hint_tolerance_mm,
                max_residual_um,
                min_points: min_points as u64,
            };
            request
                .check_for(&board)
                .map_err(|e| anyhow::anyhow!(e.for_cli()))?;
            let source = image.display().to_string();
            let mut outcome = procedure::localize::run(&request, &img, &board, &source);
            if let Some(Value::Object(frame)) =
                outcome.result.as_mut().and_then(|r| r.get_mut("image"))
            {
                frame.insert("path".into(), json!(source));
            }
            front::print(&outcome, json, procedure::localize::summary)
        }
    }
}

fn compensate(job: Job, request: CompensateRequest, json: bool) -> anyhow::Result<ExitCode> {
    request.check().map_err(|e| anyhow::anyhow!(e.for_cli()))?;
    let rt = front::runtime()?;
    let mut devices = rt.block_on(open_devices_async(&job))?;
    let mut sink = front::CliSink::new("targets", json);
    // Ctrl-C stops the job cleanly: the stage is told to stop and the report printed
    // with everything measured so far.
    let (outcome, report) = rt.block_on(procedure::compensate::run_with_report(
        &request,
        &job,
        &mut devices,
        &mut sink,
        front::ctrl_c(),
    ));
    sink.finish();
    front::print(&outcome, json, |_| report.to_text())
}
