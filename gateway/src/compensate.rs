//! `gateway demo` and `gateway compensate`: the compensation procedure on the embedded
//! demo job (over any emulated link) or a job file.

use procedure::request::CompensateRequest;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct DemoArgs {
    #[command(flatten)]
    pub request: CompensateRequest,
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
    pub request: CompensateRequest,
}

pub fn demo(a: DemoArgs, json: bool) -> anyhow::Result<ExitCode> {
    let job = procedure::demo::demo_job(&a.stage, &a.transport, &a.camera)
        .map_err(|e| anyhow::anyhow!(e.for_cli()))?;
    let mut sink = crate::front::CliSink::new("targets", json);
    crate::front::run_kind("compensate", &a.request, &mut sink, json, |f| f.job(job))
}

pub fn compensate(a: CompensateArgs, json: bool) -> anyhow::Result<ExitCode> {
    let mut sink = crate::front::CliSink::new("targets", json);
    crate::front::run_kind("compensate", &a.request, &mut sink, json, |f| {
        f.job_file(&a.config)
    })
}
