//! `emulators dnc`: a closed controller (Fanuc-style, ISO code, protocol B of the remote
//! buffer) on a new pseudo-terminal, running the simulated machine; optionally the
//! GigE Vision camera on the same machine (`--gige`), as `emulators rig` pairs it with
//! a GRBL stage. Prints `dnc: /dev/pts/N` (and `gige: ADDR:PORT`). The operator's
//! panel is standard input: a line `reset` or `start` (cycle start); alarms are printed
//! on standard error, as the control shows them on its screen.

use super::device::{DncConfig, DncDevice};
use super::pty::DncPty;
use crate::gige::device::GigeConfig;
use crate::gige::server::{GigeCameraServer, GigeServerOptions};
use anyhow::Context;
use std::io::Write;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};

#[derive(clap::Args, Debug)]
pub struct DncArgs {
    #[command(flatten)]
    pub rig: crate::rig_files::RigFiles,
    /// Also serve the GigE Vision camera on the same machine at this GVCP address.
    #[arg(long)]
    pub gige: Option<SocketAddr>,
    /// Also create a symlink to the port at this path.
    #[arg(long)]
    pub link: Option<PathBuf>,
    /// Simulated seconds per wall second, or `unconstrained` (every block runs as soon
    /// as it is read: the buffer then never fills).
    #[arg(long, default_value = "1")]
    pub time_scale: String,
    /// Write the executed path here (CSV `t_s,cmd_x_mm,cmd_y_mm,true_x_mm,true_y_mm`):
    /// truth for tests.
    #[arg(long)]
    pub trace: Option<PathBuf>,
    /// Receive buffer, characters (not stated in the public manuals).
    #[arg(long, default_value_t = DncConfig::default().buffer)]
    pub buffer: usize,
    /// DC3 when the free space falls below this (Fanuc 0: 1024).
    #[arg(long, default_value_t = DncConfig::default().dc3_free)]
    pub dc3_free: usize,
    /// DC1 when the free space is at least this again (Fanuc 0: 2048).
    #[arg(long, default_value_t = DncConfig::default().dc1_free)]
    pub dc1_free: usize,
    /// The least room a sender is given after DC3 when the buffer has less free.
    #[arg(long, default_value_t = DncConfig::default().overrun_allowance)]
    pub overrun_allowance: usize,
    /// Parameter 3401#0 DPI = 1: a number without a decimal point is in whole mm/inch
    /// (calculator type); default DPI = 0, least input increments.
    #[arg(long)]
    pub calculator_input: bool,
    /// Least input increment for G21, mm (IS-B 0.001; IS-C 0.0001).
    #[arg(long, default_value_t = 0.001)]
    pub increment_mm: f64,
    /// The block-skip switch is off (blocks starting with `/` run).
    #[arg(long)]
    pub no_block_skip: bool,
    /// A program to keep in memory for M98 (its file starts with its O number);
    /// repeatable.
    #[arg(long)]
    pub store: Vec<PathBuf>,
    /// Cycle start is pressed only on the panel (`start` on standard input); by default
    /// it is pressed whenever the control is idle.
    #[arg(long)]
    pub manual_start: bool,
}

impl DncArgs {
    pub fn config(&self) -> anyhow::Result<DncConfig> {
        let clock = self
            .time_scale
            .parse::<world::Clock>()
            .context("--time-scale")?;
        let d = DncConfig::default();
        anyhow::ensure!(
            self.dc3_free <= self.dc1_free && self.dc1_free <= self.buffer && self.buffer > 0,
            "--dc3-free {} <= --dc1-free {} <= --buffer {} is required",
            self.dc3_free,
            self.dc1_free,
            self.buffer
        );
        anyhow::ensure!(
            self.increment_mm > 0.0 && self.increment_mm.is_finite(),
            "--increment-mm must be positive"
        );
        Ok(DncConfig {
            clock,
            buffer: self.buffer,
            dc3_free: self.dc3_free,
            dc1_free: self.dc1_free,
            overrun_allowance: self.overrun_allowance,
            program: protocol::fanuc::Options {
                calculator_input: self.calculator_input,
                increment_mm: self.increment_mm,
                increment_inch: self.increment_mm / 10.0,
                block_skip: !self.no_block_skip,
                ..d.program.clone()
            },
            auto_start: !self.manual_start,
            ..d
        })
    }
}

pub fn serve(a: DncArgs) -> anyhow::Result<()> {
    let cfg = a.config()?;
    let rig = a.rig.rig()?;
    let rig = Arc::new(Mutex::new(rig));
    let mut dev = DncDevice::new(rig.clone(), cfg.clone());
    for path in &a.store {
        let text = protocol::config::read_kind(path, protocol::config::DataKind::Program)
            .with_context(|| format!("--store {}", path.display()))?;
        let o = dev
            .store_program(&text)
            .with_context(|| format!("--store {}", path.display()))?;
        eprintln!("stored O{o:04} from {}", path.display());
    }
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    rt.block_on(async move {
        let _cam = match a.gige {
            Some(bind) => {
                let cam = GigeCameraServer::spawn(
                    rig.clone(),
                    GigeServerOptions {
                        bind,
                        broadcast: bind.port() != 0,
                        config: GigeConfig {
                            clock: cfg.clock,
                            ..Default::default()
                        },
                    },
                )
                .await
                .with_context(|| format!("binding the GVCP socket on {bind}"))?;
                println!("gige: {}", cam.control_addr());
                Some(cam)
            }
            None => None,
        };
        let trace = match &a.trace {
            Some(path) => Some(
                crate::trace::TraceFile::start(rig.clone(), path)
                    .with_context(|| format!("--trace {}", path.display()))?,
            ),
            None => None,
        };
        let mut pty =
            DncPty::spawn(dev, a.link.as_deref()).context("creating the pseudo-terminal")?;
        println!("dnc: {}", pty.path());
        if let Some(l) = pty.link() {
            println!("link: {}", l.display());
        }
        std::io::stdout().flush()?;
        // The panel: standard input read on a thread of its own (lines of at most 64
        // bytes are kept; the words are short).
        let (panel_tx, mut panel) = tokio::sync::mpsc::unbounded_channel::<String>();
        std::thread::spawn(move || {
            use std::io::BufRead;
            for line in std::io::stdin().lock().lines() {
                let Ok(mut l) = line else { break };
                l.truncate(64);
                if panel_tx.send(l).is_err() {
                    break;
                }
            }
        });
        let mut alarms_shown = 0;
        let mut stats = pty.stats();
        let mut panel_open = true;
        loop {
            for alarm in stats.alarms.iter().skip(alarms_shown) {
                eprintln!("ALARM: {alarm} (press reset)");
            }
            alarms_shown = stats.alarms.len();
            tokio::select! {
                s = pty.wait_for(|s| s.alarms.len() > alarms_shown) => stats = s,
                line = panel.recv(), if panel_open => match line {
                    Some(l) if l.trim() == "reset" => pty.reset(),
                    Some(l) if l.trim() == "start" => pty.cycle_start(),
                    Some(l) => eprintln!("panel: `{}`: type `reset` or `start`", l.trim()),
                    // Standard input closed: the panel is gone, the control runs on.
                    _ => panel_open = false,
                },
                _ = tokio::signal::ctrl_c() => break,
            }
        }
        if let Some(t) = trace {
            let rows = t.finish().await?;
            eprintln!("trace: {rows} rows");
        }
        Ok(())
    })
}
