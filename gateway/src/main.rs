//! `gateway`: the command line of the compensation gateway. Every registered kind is a
//! command built from the registry ([`commands`]); the service and the demo's built-in
//! job are the only commands of their own.

use clap::{Arg, ArgAction, Command, FromArgMatches, Subcommand};
use serde_json::json;
use std::ffi::OsString;
use std::process::ExitCode;

mod commands;
mod front;
mod serve;

// The commands that are not a registered kind.
#[derive(Subcommand)]
enum Special {
    /// Run the compensation job on the embedded default: a simulated C5 stage, camera and
    /// certified board, all in-process. Reports the error against the truth.
    Demo(DemoArgs),
    /// Run the gateway as a service: machines, job queues, the HTTP/WebSocket API and
    /// the web page, as configured in BOX.toml. SIGTERM/SIGINT stop it cleanly.
    Serve {
        /// The box's configuration (see config/box/demo.toml).
        #[arg(long)]
        config: std::path::PathBuf,
    },
}

#[derive(clap::Args)]
struct DemoArgs {
    #[command(flatten)]
    request: procedure::request::CompensateRequest,
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
}

fn cli() -> Command {
    let root = Command::new("gateway")
        .version(env!("CARGO_PKG_VERSION"))
        .about("Camera + calibration board compensation gateway for X-Y stages and CNC machines")
        .subcommand_required(true)
        .arg(
            Arg::new("json")
                .long("json")
                .global(true)
                .action(ArgAction::SetTrue)
                .help(
                    "Print the outcome's result as one JSON object (the object the service \
                     stores) instead of text; errors as `{\"error\": ...}`.",
                ),
        );
    commands::add_kinds(Special::augment_subcommands(root))
}

/// `gateway rewrite IN --rotary ERRORS ...` is `gateway rotary rewrite IN --errors ERRORS ...`.
fn with_aliases(mut args: Vec<OsString>) -> Vec<OsString> {
    let command = args
        .iter()
        .skip(1)
        .position(|a| !a.to_string_lossy().starts_with('-'));
    let rotary = |a: &OsString| {
        let a = a.to_string_lossy();
        a == "--rotary" || a.starts_with("--rotary=")
    };
    if let Some(at) = command.map(|i| i + 1) {
        if args[at] == "rewrite" && args.iter().any(rotary) {
            args.splice(at..=at, ["rotary".into(), "rewrite".into()]);
            for a in args.iter_mut().filter(|a| rotary(a)) {
                *a = a
                    .to_string_lossy()
                    .replacen("--rotary", "--errors", 1)
                    .into();
            }
        }
    }
    args
}

fn main() -> ExitCode {
    let matches = cli().get_matches_from(with_aliases(std::env::args_os().collect()));
    let json_mode = matches.get_flag("json");
    match run(&matches, json_mode) {
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

fn run(matches: &clap::ArgMatches, json: bool) -> anyhow::Result<ExitCode> {
    if let Some((kind, own)) = commands::matched(matches) {
        return commands::run(kind, own, json);
    }
    match Special::from_arg_matches(matches)? {
        Special::Serve { config } => serve::serve(&config),
        Special::Demo(a) => {
            let job = procedure::demo::demo_job(&a.stage, &a.transport, &a.camera)
                .map_err(|e| anyhow::anyhow!(e.for_cli()))?;
            let kind = procedure::kinds::kind("compensate")?;
            let mut sink = front::CliSink::new(kind.steps, json);
            let outcome = front::run_outcome(kind, &a.request, &mut sink, |f| f.job(job))?;
            front::print(&outcome, json, |r| kind.summary(r))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The command line is well formed (clap's own checks: no flag declared twice, every
    /// `requires` and `conflicts_with` naming an argument).
    #[test]
    fn the_command_line_is_well_formed() {
        cli().debug_assert();
    }

    /// Every registered kind is a command under its words, and its flags are the
    /// request's fields: each one left out on the command line takes the API's default
    /// for it (the defaults are declared once).
    #[test]
    fn the_command_line_and_the_api_default_every_parameter_alike() {
        for k in procedure::KINDS {
            let mut args: Vec<String> = vec!["gateway".into()];
            args.extend(k.command.split(' ').map(String::from));
            for file in k.files.iter().filter(|f| f.required) {
                if !file.positional {
                    args.push(format!("--{}", file.name));
                }
                args.push("f".into());
            }
            // A flag with no default (ISO 230-2's axis, a layout's tools).
            const LAYOUT: &[&str] = &["--tools", "2", "--window-mm", "100", "--gap-mm", "5"];
            let needed = [
                ("iso230", &["--axis", "x"][..]),
                ("layout", LAYOUT),
                ("cut", LAYOUT),
                ("export", &["--format", "csv"]),
                ("volumetric-identify", &["--structure", "XYZF"]),
            ];
            for (_, flags) in needed.iter().filter(|(n, _)| *n == k.name) {
                args.extend(flags.iter().map(|f| f.to_string()));
            }
            if k.name == "dnc" {
                args.extend(["p.nc".into(), "--uncompensated".into()]);
            }
            let matches = cli()
                .try_get_matches_from(&args)
                .unwrap_or_else(|e| panic!("{args:?}: {e}"));
            let (kind, own) = commands::matched(&matches).unwrap();
            assert_eq!(kind.name, k.name);
            let flags = kind.from_flags(own).unwrap();
            for (key, value) in flags.as_object().unwrap() {
                let mut without = flags.clone();
                without.as_object_mut().unwrap().remove(key);
                // A field the API requires (the program, the layout) has no default.
                if let Ok(api) = kind.parse(&without) {
                    let given = [("dnc", "uncompensated")].contains(&(k.name, key.as_str()))
                        || needed.iter().any(|(n, f)| {
                            *n == k.name
                                && f.contains(&format!("--{}", key.replace('_', "-")).as_str())
                        });
                    if !given {
                        assert_eq!(api[key], *value, "{}.{key}: {flags}", k.name);
                    }
                }
            }
        }
    }

    #[test]
    fn rewrite_with_rotary_is_the_rotary_rewrite() {
        let args = |a: &[&str]| a.iter().map(OsString::from).collect::<Vec<_>>();
        assert_eq!(
            with_aliases(args(&[
                "gateway", "--json", "rewrite", "p.nc", "--rotary", "e.json", "--out", "o"
            ])),
            args(&[
                "gateway", "--json", "rotary", "rewrite", "p.nc", "--errors", "e.json", "--out",
                "o"
            ])
        );
        assert_eq!(
            with_aliases(args(&["gateway", "rewrite", "p.nc", "--map", "m"])),
            args(&["gateway", "rewrite", "p.nc", "--map", "m"])
        );
    }
}
