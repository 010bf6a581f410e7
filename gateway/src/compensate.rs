//! `gateway demo` and `gateway compensate`: the compensation procedure on the embedded
//! demo job (over any emulated link) or a job file.

use devices::open_devices_async;
use job::Job;
use procedure::request::CompensateRequest;
use std::path::PathBuf;
use std::process::ExitCode;

/// The flags of a compensation run, whichever job it is on.
#[derive(clap::Args)]
pub struct RunFlags {
    /// Print one JSON object instead of the table.
    #[arg(long)]
    pub json: bool,
    /// Localization method: fit (default) or four-point (the patent's formula).
    #[arg(long)]
    pub method: Option<String>,
    /// Only the first N targets.
    #[arg(long)]
    pub targets: Option<u64>,
}

impl RunFlags {
    /// The request the flags describe.
    fn request(&self) -> anyhow::Result<CompensateRequest> {
        Ok(CompensateRequest {
            targets: self.targets,
            method: self
                .method
                .as_deref()
                .map(crate::front::parse_method)
                .transpose()?,
        })
    }
}

#[derive(clap::Args)]
pub struct DemoArgs {
    #[command(flatten)]
    pub run: RunFlags,
    /// Stage backend: `sim` (in-process) or `grbl` (the GRBL emulator on a real
    /// pseudo-terminal, driven by the GRBL serial driver); `modbus` (the Modbus
    /// drive emulator); `canopen` (CiA 402 drive emulator behind an SLCAN adapter
    /// on a real pseudo-terminal, driven by the CANopen driver).
    #[arg(long, default_value = "sim")]
    pub stage: String,
    /// With `--stage modbus`: `tcp` (drive emulator on a loopback port) or `rtu`
    /// (on a real pseudo-terminal).
    #[arg(long, default_value = "tcp")]
    pub transport: String,
    /// Camera link: `sim` (in-process) or `gige` (the GigE Vision emulator on a
    /// loopback UDP port, rendering the same machine, read by the GigE driver).
    #[arg(long, default_value = "sim")]
    pub camera: String,
}

#[derive(clap::Args)]
pub struct CompensateArgs {
    #[arg(long)]
    pub config: PathBuf,
    #[command(flatten)]
    pub run: RunFlags,
}

pub fn demo(a: DemoArgs) -> anyhow::Result<ExitCode> {
    let job = procedure::demo::demo_job(&a.stage, &a.transport, &a.camera)
        .map_err(|e| anyhow::anyhow!(e.for_cli()))?;
    run(job, a.run.request()?, a.run.json)
}

pub fn compensate(a: CompensateArgs) -> anyhow::Result<ExitCode> {
    run(Job::load(&a.config)?, a.run.request()?, a.run.json)
}

fn run(job: Job, request: CompensateRequest, json: bool) -> anyhow::Result<ExitCode> {
    request.check().map_err(|e| anyhow::anyhow!(e.for_cli()))?;
    let rt = crate::front::runtime()?;
    let mut devices = rt.block_on(open_devices_async(&job))?;
    let mut sink = crate::front::CliSink::new("targets", json);
    // Ctrl-C stops the job cleanly: the stage is told to stop and the report printed
    // with everything measured so far.
    let (outcome, report) = rt.block_on(procedure::compensate::run_with_report(
        &request,
        &job,
        &mut devices,
        &mut sink,
        crate::front::ctrl_c(),
    ));
    sink.finish();
    crate::front::print(&outcome, json, |_| report.to_text())
}
