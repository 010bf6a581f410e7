//! `gateway verify`: the verification procedure, once or as a periodic spot check.

use devices::open_devices_async;
use job::Job;
use procedure::request::VerifyRequest;
use protocol::errormap::ErrorMap;
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
    /// With --spot-check: home and re-reference instead of using the map's recorded
    /// reference (MAP.reference.json).
    #[arg(long)]
    pub no_reference: bool,
}

pub fn verify(args: VerifyArgs, json: bool) -> anyhow::Result<ExitCode> {
    let request = args.request;
    request.check().map_err(|e| anyhow::anyhow!(e.for_cli()))?;
    anyhow::ensure!(args.repeat >= 1, "--repeat must be at least 1");
    // A week at most: a pause beyond it is no watch (and 1e308 s is no Duration).
    let s = args.every_s;
    anyhow::ensure!(
        (0.0..=604_800.0).contains(&s),
        "--every-s must be a number of seconds from 0 to 604800 (a week), got {}",
        if s.abs() < 1e6 {
            s.to_string()
        } else {
            format!("{s:e}")
        }
    );
    let job = Job::load(&args.config)?;
    let map = ErrorMap::load(&args.map)?;
    // A spot check uses the map's current reference (as rewrite and proxy do).
    let reference = match request.spot_check && !args.no_reference {
        true => procedure::reference::read_record(&procedure::reference::reference_path(&args.map))
            .map_err(anyhow::Error::msg)?,
        false => None,
    };
    if request.spot_check && !args.no_reference && reference.is_none() {
        eprintln!(
            "warning: no reference is recorded for {}: the spot check homes and re-references \
             (run `gateway reference` after every homing)",
            args.map.display()
        );
    }
    let rt = crate::front::runtime()?;
    let mut devices = rt.block_on(open_devices_async(&job))?;
    let what = args.map.display().to_string();
    let mut any_drifted = false;
    for round in 0..args.repeat {
        if round > 0 {
            // The timer must be made inside the runtime (tokio panics otherwise).
            let pause = std::time::Duration::from_secs_f64(args.every_s);
            rt.block_on(async { tokio::time::sleep(pause).await });
        }
        if args.repeat > 1 && !json {
            println!("check {} of {}:", round + 1, args.repeat);
        }
        let mut sink = crate::front::CliSink::new("points", true);
        let outcome = rt.block_on(procedure::verify::run_with_reference(
            &request,
            &job,
            &mut devices,
            map.clone(),
            &what,
            round as u64,
            reference.as_ref(),
            &mut sink,
        ));
        let code = crate::front::print(&outcome, json, procedure::verify::summary)?;
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
