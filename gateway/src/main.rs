//! `gateway`: the command line of the compensation gateway.

use clap::{Parser, Subcommand};

use serde_json::json;
use std::process::ExitCode;

mod compensate;
mod export;
mod front;
mod iso230;
mod layout;
mod localize;
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
    Demo(compensate::DemoArgs),
    /// Run the compensation job described by a configuration file.
    Compensate(compensate::CompensateArgs),
    /// Scan the machine into an error map: a grid over the travel and dense lines along
    /// each axis, every point approached from both sides, `--passes` times. Written as a
    /// new version OUT/NAME.vN.json (never over an older one); a stopped scan resumes
    /// from its journal OUT/NAME.scan.jsonl.
    Map(scan::MapArgs),
    /// Rewrite a G-code program so that every move lands where it was programmed: moves
    /// split against the tolerance, arcs as chords, each point replaced by the command
    /// the error map gives for it. The controller's dialect is GRBL 1.1: what it would
    /// refuse is refused here first, naming the line.
    Rewrite(rewrite::RewriteArgs),
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
    Localize(localize::LocalizeArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let json_mode = match &cli.cmd {
        Cmd::Demo(a) => a.run.json,
        Cmd::Compensate(a) => a.run.json,
        Cmd::Rewrite(a) => a.json,
        Cmd::Localize(a) => a.json,
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
        Cmd::Demo(a) => compensate::demo(a),
        Cmd::Compensate(a) => compensate::compensate(a),
        Cmd::Map(a) => scan::map(a),
        Cmd::Rewrite(a) => rewrite::rewrite(a),
        Cmd::Layout { cmd } => layout::run(cmd),
        Cmd::Serve { config } => serve::serve(&config),
        Cmd::Proxy(a) => proxy::proxy(a),
        Cmd::Rotary { cmd } => rotary::run(cmd),
        Cmd::Iso230(a) => iso230::dispatch(a),
        Cmd::Verify(a) => verify::verify(a),
        Cmd::Export(a) => export::export(a),
        Cmd::Localize(a) => localize::localize(a),
    }
}
