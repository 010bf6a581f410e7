//! `gateway verify`: the verification procedure, once or as a periodic spot check.

use procedure::files::Files;
use procedure::request::VerifyRequest;
use procedure::Stop;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct VerifyArgs {
    #[arg(long)]
    pub config: PathBuf,
    #[arg(long)]
    pub map: PathBuf,
    #[command(flatten)]
    pub request: VerifyRequest,
    /// Checks in a row, each on fresh points (a periodic spot check; exit code 2
    /// when any is past the threshold).
    #[arg(long, default_value_t = 1)]
    pub repeat: usize,
    /// Seconds between two checks of --repeat.
    #[arg(long, default_value_t = 600.0)]
    pub every_s: f64,
}

pub fn verify(args: VerifyArgs, json: bool) -> anyhow::Result<ExitCode> {
    anyhow::ensure!(
        (1..=1_000_000).contains(&args.repeat),
        "--repeat must be from 1 to 1000000, got {}",
        args.repeat
    );
    // At most a week between two checks (a longer pause is a mistyped flag).
    const WEEK_S: f64 = 7.0 * 24.0 * 3600.0;
    anyhow::ensure!(
        args.every_s.is_finite() && (0.0..=WEEK_S).contains(&args.every_s),
        "--every-s must be a number of seconds from 0 to {WEEK_S} (a week), got {:?}",
        args.every_s
    );
    let kind = procedure::kinds::kind("verify").map_err(|e| anyhow::anyhow!("{e}"))?;
    let rt = crate::front::runtime()?;
    let mut sink = crate::front::CliSink::new("points", true);
    let (raise, stop) = Stop::new();
    let mut any_drifted = false;
    // One files context for every round: the devices are opened once.
    let mut files = Files::new(&mut sink, stop.clone())
        .job_file(&args.config)
        .map_file(&args.map);
    let _watcher = rt.spawn(async move {
        crate::front::ctrl_c().await;
        let _ = raise.send(true);
    });
    for round in 0..args.repeat {
        if round > 0 {
            let pause = std::time::Duration::from_secs_f64(args.every_s);
            let stopped = rt.block_on(async {
                tokio::select! {
                    _ = tokio::time::sleep(pause) => false,
                    _ = stop.clone().requested() => true,
                }
            });
            if stopped {
                break;
            }
        }
        if args.repeat > 1 && !json {
            println!("check {} of {}:", round + 1, args.repeat);
        }
        let mut request = args.request.clone();
        request.round = round as u64;
        let params = kind
            .parse(&serde_json::to_value(&request)?)
            .map_err(|e| anyhow::anyhow!(e.for_cli()))?;
        let outcome = rt.block_on(kind.run(params, &mut files));
        let code = crate::front::print(&outcome, json, |r| kind.summary(r))?;
        if code != ExitCode::SUCCESS {
            return Ok(code);
        }
        any_drifted |= outcome.result.as_ref().is_some_and(|r| r["rescan"] == true);
    }
    Ok(if any_drifted {
        ExitCode::from(2)
    } else {
        ExitCode::SUCCESS
    })
}
