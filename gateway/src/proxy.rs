//! `gateway proxy`: the live pass-through between the operator's sender and the GRBL
//! controller, every line rewritten with the error map or for the rotary table.

use anyhow::Context;
use errormap::MapModel;
use job::{GrblLink, Job, StageSpec};
use protocol::errormap::ErrorMap;
use proxy::{open_controller, serve, Ending, FiveAxisRewriter, LineAccount, Proxy, SenderPort};
use rewrite::{Compensation, Options, Rewriter};
use serde_json::json;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

pub struct ProxyArgs {
    pub config: Option<PathBuf>,
    pub map: Option<PathBuf>,
    pub rotary: Option<PathBuf>,
    pub machine: Option<PathBuf>,
    pub controller: Option<String>,
    pub baud: u32,
    pub link: Option<PathBuf>,
    pub tolerance_um: f64,
    pub max_correction_um: Option<f64>,
    /// For an emulated controller: simulated seconds per wall second, or `unconstrained`.
    pub time_scale: String,
    /// Serve one sender session, then exit (tests, scripted runs).
    pub once: bool,
    pub json: bool,
}

/// How long to wait for a controller's banner after opening its port (an Arduino resets
/// when the port opens and needs about two seconds).
const BANNER_WAIT: Duration = Duration::from_millis(2500);

fn ranges(lines: &[u64]) -> String {
    let mut out: Vec<String> = Vec::new();
    let mut k = 0;
    while k < lines.len() {
        let start = lines[k];
        let mut end = start;
        while k + 1 < lines.len() && lines[k + 1] == end + 1 {
            k += 1;
            end = lines[k];
        }
        out.push(if start == end {
            start.to_string()
        } else {
            format!("{start}-{end}")
        });
        k += 1;
    }
    if out.is_empty() {
        "none".into()
    } else {
        out.join(", ")
    }
}

fn account_json(a: &LineAccount) -> serde_json::Value {
    json!({
        "acknowledged": ranges(&a.acknowledged), "refused": ranges(&a.refused),
        "in_controller": ranges(&a.in_controller), "not_sent": ranges(&a.not_sent),
    })
}

pub fn proxy(args: ProxyArgs) -> anyhow::Result<ExitCode> {
    match (&args.config, &args.map, &args.rotary, &args.controller) {
        (Some(config), Some(map), None, None) => proxy_map(&args, config, map),
        (None, None, Some(errors), Some(port)) => proxy_rotary(&args, errors, port),
        _ => anyhow::bail!(
            "give `--config JOB --map MAP` (the error map, the job's GRBL controller) or \
             `--rotary ERRORS --controller PORT` (the rotary table's errors, a grblHAL \
             controller with A and C)"
        ),
    }
}

fn proxy_map(
    args: &ProxyArgs,
    config: &std::path::Path,
    map_path: &std::path::Path,
) -> anyhow::Result<ExitCode> {
    let job = Job::load(config)?;
    let map = ErrorMap::load(map_path)?;
    // The map must belong to this machine, controller, board certificate and camera:
    // the one identity check of every procedure, on the job's devices (opened, asked,
    // closed) before the controller's port is opened for the pass-through.
    let here = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?
        .block_on(procedure::identity_of_job(&job))
        .map_err(|e| anyhow::anyhow!(e))?;
    procedure::check_identity(&map, &here, &map_path.display().to_string())
        .map_err(|e| anyhow::anyhow!(e))?;
    let model = MapModel::new(map);
    let StageSpec::Grbl { link, baud } = &job.stage else {
        anyhow::bail!(
            "{}: the pass-through needs a GRBL controller (stage kind `grbl`); other controllers take the map as a table (gateway export)",
            config.display()
        );
    };
    let options = Options {
        tolerance_mm: args.tolerance_um / 1000.0,
        max_correction_mm: args.max_correction_um.unwrap_or(200.0) / 1000.0,
        ..Options::default()
    };
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    rt.block_on(async {
        let (port, _emulator) = match link {
            GrblLink::Port(p) => (p.clone(), None),
            GrblLink::Emulate(machine) => {
                let clock = args
                    .time_scale
                    .parse::<world::Clock>()
                    .context("--time-scale")?;
                let (emulator, rig) = devices::spawn_grbl_emulator(&job, machine, clock)?;
                (emulator.path().to_string(), Some((emulator, rig)))
            }
        };
        sessions(args, &port, *baud, &model.describe(), || {
            let rewriter = Rewriter::new(&model, options.clone())?;
            Ok(Proxy::new(rewriter, &model))
        })
        .await
    })
}

fn proxy_rotary(
    args: &ProxyArgs,
    errors_path: &std::path::Path,
    port: &str,
) -> anyhow::Result<ExitCode> {
    let text = std::fs::read_to_string(errors_path)
        .with_context(|| format!("reading {}", errors_path.display()))?;
    let errors = rotary::LocationErrors::from_json(&text)
        .map_err(|e| anyhow::anyhow!("{}: {e}", errors_path.display()))?;
    let constants = crate::rotary::load_constants(args.machine.as_deref())?;
    let model = rotary::RotaryMachine::with_errors(constants, errors);
    let options = rotary::rewrite::RewriteOptions {
        tolerance_mm: args.tolerance_um / 1000.0,
        max_correction_mm: args.max_correction_um.unwrap_or(2000.0) / 1000.0,
        ..Default::default()
    };
    let describe = format!("rotary table errors {}", errors_path.display());
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    rt.block_on(sessions(args, port, args.baud, &describe, || {
        Ok(Proxy::with_rewriter(Box::new(FiveAxisRewriter::new(
            rotary::rewrite::RotaryRewriter::new(&model, options),
        ))))
    }))
}

/// Serves sender sessions one after another (or one with `--once`) until Ctrl-C or the
/// controller is lost, each with a fresh pass-through from `make`.
async fn sessions<'m>(
    args: &ProxyArgs,
    port: &str,
    baud: u32,
    describe: &str,
    mut make: impl FnMut() -> anyhow::Result<Proxy<'m>>,
) -> anyhow::Result<ExitCode> {
    let (mut controller, _banner) = open_controller(port, baud, BANNER_WAIT).await?;
    let mut sender = SenderPort::create(args.link.as_deref())
        .context("creating the sender's pseudo-terminal")?;
    if args.json {
        println!(
            "{}",
            json!({ "sender_port": sender.path(), "controller": port, "compensation": describe, "map": describe })
        );
    } else {
        println!("sender port: {}", sender.path());
        if let Some(l) = sender.link() {
            println!("link: {}", l.display());
        }
        println!("controller: {port}; compensation: {describe}");
    }
    use std::io::Write;
    std::io::stdout().flush()?;
    let mut code = ExitCode::SUCCESS;
    loop {
        let mut proxy = make()?;
        proxy.start();
        let stop = async {
            if tokio::signal::ctrl_c().await.is_err() {
                std::future::pending::<()>().await;
            }
        };
        let ending = serve(&mut proxy, &mut sender, &mut controller, stop).await;
        let stats = proxy.stats();
        let pct = |v: &[f64], q: f64| {
            let mut v = v.to_vec();
            v.sort_by(f64::total_cmp);
            if v.is_empty() {
                0.0
            } else {
                v[((v.len() - 1) as f64 * q).round() as usize] * 1000.0
            }
        };
        let (lat, work) = (&stats.latencies_s, &stats.processing_s);
        let (what, lines, done) = match &ending {
            Ending::SenderLeft(a) => ("sender left", a, false),
            Ending::ControllerLost { why, lines } => {
                code = ExitCode::FAILURE;
                eprintln!("controller lost: {why}");
                ("controller lost", lines, true)
            }
            Ending::Stopped(a) => ("stopped", a, true),
        };
        let report = rewriter_report(&proxy);
        if args.json {
            println!(
                "{}",
                json!({
                    "ending": what, "lines": account_json(lines),
                    "lines_received": stats.lines, "pieces_sent": stats.pieces_sent,
                    "starvation_events": stats.starvation_events,
                    "rewrite_ms": { "median": pct(work, 0.5), "p99": pct(work, 0.99) },
                    "first_piece_out_ms": { "median": pct(lat, 0.5), "p99": pct(lat, 0.99) },
                    "largest_correction_um": report.0, "segments_added": report.1,
                })
            );
        } else {
            println!(
                "session ended ({what}): {} lines received, {} pieces sent, {} starvation events",
                stats.lines, stats.pieces_sent, stats.starvation_events
            );
            println!("  rewrite per line: median {:.3} ms, p99 {:.3} ms; arrival to first piece out: median {:.3} ms, p99 {:.3} ms",
                pct(work, 0.5), pct(work, 0.99), pct(lat, 0.5), pct(lat, 0.99));
            println!("  acknowledged: {}", ranges(&lines.acknowledged));
            println!("  refused: {}", ranges(&lines.refused));
            println!(
                "  in the controller when it ended: {}",
                ranges(&lines.in_controller)
            );
            println!("  never sent: {}", ranges(&lines.not_sent));
        }
        std::io::stdout().flush()?;
        if done || args.once {
            break;
        }
    }
    Ok(code)
}

fn rewriter_report(proxy: &Proxy<'_>) -> (f64, usize) {
    proxy.rewriter().summary()
}
