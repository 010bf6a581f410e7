//! `gateway proxy`: the live pass-through between the operator's sender and the GRBL
//! controller, every line rewritten with the error map or for the rotary table. The
//! procedure is `procedure::proxy`; here the flags become its request, the files are
//! read, and what it reports is printed as it comes.

use procedure::proxy::{Correction, Inputs, ProxyFront, ProxyRequest};
use serde_json::Value;
use std::path::PathBuf;
use std::process::ExitCode;

#[derive(clap::Args)]
pub struct ProxyArgs {
    /// The job file (its stage must be a GRBL controller, real or emulated); with
    /// `--map`.
    #[arg(long)]
    pub config: Option<PathBuf>,
    #[arg(long)]
    pub map: Option<PathBuf>,
    /// The rotary table's errors (the JSON `gateway rotary measure` or `identify`
    /// writes); with `--controller`.
    #[arg(long)]
    pub rotary: Option<PathBuf>,
    /// The machine constants of the rotary table (JSON), default the built-in ones.
    #[arg(long)]
    pub machine: Option<PathBuf>,
    /// The controller's serial port, with `--rotary`.
    #[arg(long)]
    pub controller: Option<String>,
    /// Also create a symlink to the sender's port at this path.
    #[arg(long)]
    pub link: Option<PathBuf>,
    /// With --map: apply the map as scanned, without its recorded reference
    /// (MAP.reference.json, written by `gateway reference` after a homing).
    #[arg(long, requires = "map")]
    pub no_reference: bool,
    #[command(flatten)]
    pub request: ProxyRequest,
}

/// Prints the ready message and each session but the last as they come.
struct Printer {
    json: bool,
    link: Option<PathBuf>,
    /// Where the map's current reference is kept (beside the map).
    record_to: Option<PathBuf>,
}

impl Printer {
    fn show(&self, v: &Value, text: impl FnOnce(&Value) -> String) -> Result<(), procedure::Error> {
        let mut shown = if self.json { v.to_string() } else { text(v) };
        if !shown.ends_with('\n') {
            shown.push('\n');
        }
        crate::front::emit(&shown)
            .map_err(|e| procedure::Error::Output(format!("writing to stdout: {e}")))
    }
}

impl ProxyFront for Printer {
    fn ready(&mut self, hello: &Value) -> Result<(), procedure::Error> {
        self.show(hello, |h| {
            procedure::proxy::ready_summary(h, self.link.as_deref())
        })
    }

    fn session(&mut self, account: &Value) -> Result<(), procedure::Error> {
        self.show(account, procedure::proxy::summary)
    }

    fn reference(
        &mut self,
        record: &errormap::reference::MapReference,
    ) -> Result<(), procedure::Error> {
        let Some(path) = &self.record_to else {
            return Ok(());
        };
        let text = procedure::reference::record_json(record);
        protocol::config::replace_output(path, text.as_bytes(), &[]).map_err(|e| {
            procedure::Error::Output(format!(
                "recording the reference in {}: {e}",
                path.display()
            ))
        })?;
        let v = serde_json::json!({"reference_recorded": path.display().to_string(),
            "reference_count": record.reference_count, "shift_um": record.shift_um});
        self.show(&v, |_| {
            format!(
                "after the sender's homing: reference #{} recorded in {}, machine zero shift ({:+.2}, {:+.2}) um\n",
                record.reference_count,
                path.display(),
                record.shift_um[0],
                record.shift_um[1]
            )
        })
    }
}

pub fn proxy(args: ProxyArgs, json: bool) -> anyhow::Result<ExitCode> {
    let request = args.request;
    request.check().map_err(|e| anyhow::anyhow!(e.for_cli()))?;
    let inputs = procedure::proxy::inputs(args.config, args.map, args.rotary, args.controller)
        .map_err(|e| anyhow::anyhow!(e))?;
    let record_to = match &inputs {
        Inputs::Map { map, .. } => Some(procedure::reference::reference_path(map)),
        Inputs::Rotary { .. } => None,
    };
    let correction = Correction::from_files(inputs, args.machine.as_deref(), args.no_reference)
        .map_err(anyhow::Error::msg)?;
    let mut printer = Printer {
        json,
        link: args.link.clone(),
        record_to,
    };
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let outcome = rt.block_on(procedure::proxy::run(
        &request,
        correction,
        args.link.as_deref(),
        &mut printer,
        crate::front::ctrl_c(),
    ));
    crate::front::print(&outcome, json, procedure::proxy::summary)
}
