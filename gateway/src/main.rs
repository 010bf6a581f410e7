//! `gateway`: the command line of the compensation gateway.

use clap::{Parser, Subcommand};

use serde_json::json;
use std::process::ExitCode;

mod board;
mod compensate;
mod dnc;
mod export;
mod front;
mod iso230;
mod layout;
mod localize;
mod proxy;
mod reference;
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
    /// Print the outcome's result as one JSON object (the object the service stores)
    /// instead of text; errors as `{"error": ...}`.
    #[arg(long, global = true)]
    json: bool,
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
    /// After every homing: home (when the job homes), one frame at the map's reference
    /// point, and the machine zero's shift recorded beside the map as its current
    /// reference (MAP.reference.json), which rewrite, proxy and verify --spot-check apply.
    Reference(reference::ReferenceArgs),
    /// Write the map as a controller's own compensation table: `linuxcnc` (a COMP_FILE
    /// per joint, nominal/forward/reverse, at most 256 entries), `beckhoff` (a TwinCAT
    /// CNC plane compensation list per axis over X and Y) or `csv` (the model on the
    /// map's grid). Each says what the format cannot hold and refuses a table further
    /// from the map than the tolerance.
    Export(export::ExportArgs),
    /// Localize one image of the board: the board coordinate under the image centre.
    Localize(localize::LocalizeArgs),
    /// Calibration boards: `make` writes a board's artwork (DXF, SVG at 1:1, a PDF test
    /// print) and its certificate template.
    Board {
        #[command(subcommand)]
        cmd: board::BoardCmd,
    },
    /// Drip-feed a Fanuc program to a closed controller through its tape port (DNC,
    /// DC1/DC3), rewritten with the error map; what cannot be rewritten exactly is
    /// refused naming the block.
    Dnc(dnc::DncArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let json_mode = cli.json;
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
    let json = cli.json;
    match cli.cmd {
        Cmd::Volumetric { cmd } => volumetric::run(cmd, json),
        Cmd::Demo(a) => compensate::demo(a, json),
        Cmd::Compensate(a) => compensate::compensate(a, json),
        Cmd::Map(a) => scan::map(a, json),
        Cmd::Rewrite(a) => rewrite::rewrite(a, json),
        Cmd::Layout { cmd } => layout::run(cmd, json),
        Cmd::Serve { config } => serve::serve(&config),
        Cmd::Proxy(a) => proxy::proxy(a, json),
        Cmd::Rotary { cmd } => rotary::run(cmd, json),
        Cmd::Iso230(a) => iso230::dispatch(a, json),
        Cmd::Verify(a) => verify::verify(a, json),
        Cmd::Reference(a) => reference::reference(a, json),
        Cmd::Export(a) => export::export(a, json),
        Cmd::Localize(a) => localize::localize(a, json),
        Cmd::Board { cmd } => board::run(cmd, json),
        Cmd::Dnc(a) => dnc::dnc(a, json),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use procedure::Request;
    use serde_json::Value;

    fn parse(args: &[&str]) -> Cmd {
        let mut all = vec!["gateway"];
        all.extend_from_slice(args);
        Cli::try_parse_from(all).unwrap().cmd
    }

    fn api(kind: &str, params: Value) -> Value {
        Request::parse(kind, &params).unwrap().params()
    }

    /// Every registered procedure is a command of this binary (the registry's
    /// `COMMAND` words name it).
    #[test]
    fn every_registered_kind_is_a_command() {
        use clap::CommandFactory;
        let cli = Cli::command();
        for k in procedure::KINDS {
            let mut cmd = &cli;
            for word in k.command.split(' ') {
                cmd = cmd.find_subcommand(word).unwrap_or_else(|| {
                    panic!("kind {}: no command `gateway {}`", k.name, k.command)
                });
            }
        }
    }

    /// The flags are the request's fields: with no flag given, the CLI's request is the
    /// API's request with no param given (the defaults are declared once).
    #[test]
    fn the_command_line_and_the_api_default_every_parameter_alike() {
        let Cmd::Demo(a) = parse(&["demo"]) else {
            panic!()
        };
        assert_eq!(json!(a.request), api("compensate", json!({})));
        let Cmd::Map(a) = parse(&["map", "--config", "j", "--out", "o"]) else {
            panic!()
        };
        assert_eq!(json!(a.request), api("map", json!({})));
        let Cmd::Verify(a) = parse(&["verify", "--config", "j", "--map", "m"]) else {
            panic!()
        };
        assert_eq!(json!(a.request), api("verify", json!({})));
        let Cmd::Reference(a) = parse(&["reference", "--config", "j", "--map", "m"]) else {
            panic!()
        };
        let from_api = procedure::request::ReferenceRequest::parse(&json!({})).unwrap();
        assert_eq!(a.request, from_api);
        let Cmd::Iso230(a) = parse(&["iso230", "--config", "j", "--out", "o", "--axis", "X"])
        else {
            panic!()
        };
        assert_eq!(json!(a.request), api("iso230", json!({"axis": "x"})));
        let layout = json!({"layout": "", "format": "json", "tools": 2, "window_mm": 100.0,
            "gap_mm": 5.0});
        let flags = [
            "l.json",
            "--tools",
            "2",
            "--window-mm",
            "100",
            "--gap-mm",
            "5",
        ];
        let Cmd::Layout {
            cmd: layout::LayoutCmd::Cut { request, .. },
        } = parse(&[&["layout", "cut"][..], &flags].concat())
        else {
            panic!()
        };
        let cut: procedure::request::CutRequest =
            serde_json::from_value(json!({ "partition": layout })).unwrap();
        assert_eq!(request, cut);
        let Cmd::Rewrite(a) = parse(&["rewrite", "p.nc", "--map", "m", "--out", "o"]) else {
            panic!()
        };
        let api: procedure::rewrite::RewriteRequest =
            serde_json::from_value(json!({"program": ""})).unwrap();
        assert_eq!(a.request, api);
        let Cmd::Rotary {
            cmd: rotary::RotaryCmd::Rewrite { request, .. },
        } = parse(&["rotary", "rewrite", "p.nc", "--errors", "e", "--out", "o"])
        else {
            panic!()
        };
        let api: procedure::rotary::RotaryRewriteRequest =
            serde_json::from_value(json!({"program": "", "errors": ""})).unwrap();
        assert_eq!(request, api);
        let Cmd::Dnc(a) = parse(&["dnc", "p.nc", "--map", "m"]) else {
            panic!()
        };
        let api: procedure::dnc::DncRequest =
            serde_json::from_value(json!({"program": ""})).unwrap();
        assert_eq!(a.request, api);
        let Cmd::Dnc(a) = parse(&[
            "dnc",
            "p.nc",
            "--uncompensated",
            "--no-send",
            "--out",
            "o",
            "--no-block-skip",
            "--work-offsets",
            "1,2,3;4,5,6",
        ]) else {
            panic!()
        };
        assert!(!a.request.send && !a.request.block_skip && a.request.uncompensated);
        assert_eq!(
            a.request.work_offsets,
            Some(vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
        );
        let Cmd::Proxy(a) = parse(&["proxy", "--config", "j", "--map", "m"]) else {
            panic!()
        };
        let api: procedure::proxy::ProxyRequest = serde_json::from_value(json!({})).unwrap();
        assert_eq!(a.request, api);
        let Cmd::Localize(a) = parse(&["localize", "f.png", "--board", "b", "--near", "-1,2"])
        else {
            panic!()
        };
        let api: procedure::localize::LocalizeRequest =
            serde_json::from_value(json!({"near": [-1.0, 2.0]})).unwrap();
        assert_eq!(a.request, api);
    }
}
