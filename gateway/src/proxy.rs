//! `gateway proxy`: the live pass-through between the operator's sender and the GRBL
//! controller, every line rewritten with the error map or for the rotary table. The
//! procedure is `procedure::proxy`; here the flags become its request, the files are
//! read, and what it reports is printed as it comes.

use anyhow::Context;
use job::Job;
use procedure::proxy::{Correction, Inputs, ProxyFront, ProxyRequest};
use protocol::errormap::ErrorMap;
use serde_json::Value;
use std::path::PathBuf;
use std::process::ExitCode;

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

/// Prints the ready message and each session but the last as they come.
struct Printer {
    json: bool,
    link: Option<PathBuf>,
}

impl Printer {
    fn show(&self, v: &Value, text: impl FnOnce(&Value) -> String) -> Result<(), String> {
        let mut shown = if self.json { v.to_string() } else { text(v) };
        if !shown.ends_with('\n') {
            shown.push('\n');
        }
        crate::front::emit(&shown).map_err(|e| format!("writing to stdout: {e}"))
    }
}

impl ProxyFront for Printer {
    fn ready(&mut self, hello: &Value) -> Result<(), String> {
        self.show(hello, |h| {
            procedure::proxy::ready_summary(h, self.link.as_deref())
        })
    }

    fn session(&mut self, account: &Value) -> Result<(), String> {
        self.show(account, procedure::proxy::summary)
    }
}

pub fn proxy(args: ProxyArgs) -> anyhow::Result<ExitCode> {
    let request = ProxyRequest {
        tolerance_um: args.tolerance_um,
        max_correction_um: args.max_correction_um,
        baud: args.baud,
        time_scale: args.time_scale,
        once: args.once,
    };
    request.check().map_err(|e| anyhow::anyhow!(e.for_cli()))?;
    let inputs = procedure::proxy::inputs(args.config, args.map, args.rotary, args.controller)
        .map_err(|e| anyhow::anyhow!(e))?;
    let correction = match inputs {
        Inputs::Map { job, map } => Correction::Map {
            job: Box::new(Job::load(&job)?),
            job_source: job.display().to_string(),
            map: Box::new(ErrorMap::load(&map)?),
            map_source: map.display().to_string(),
        },
        Inputs::Rotary { errors, controller } => {
            let text = protocol::config::read_data_file(&errors)
                .with_context(|| format!("reading {}", errors.display()))?;
            Correction::Rotary {
                errors: rotary::LocationErrors::from_json(&text)
                    .map_err(|e| anyhow::anyhow!("{}: {e}", errors.display()))?,
                constants: crate::rotary::load_constants(args.machine.as_deref())?,
                source: errors.display().to_string(),
                controller,
            }
        }
    };
    let mut printer = Printer {
        json: args.json,
        link: args.link.clone(),
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
    crate::front::print(&outcome, args.json, procedure::proxy::summary)
}
