//! The `emulators canopen` command: CiA 402 drive nodes on the simulated machine,
//! behind an emulated SLCAN adapter on a new pseudo-terminal (prints
//! `slcan: /dev/pts/N`), served until killed.

use super::drives::{DriveSet, DriveSetConfig, DRIVE_EDS, DRIVE_EDS_NAME};
use super::pty::SlcanPty;
use anyhow::Context;
use std::io::Write;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};

/// Serve CiA 402 drives (one node per machine axis) behind an SLCAN adapter on a new
/// pseudo-terminal; prints the port path and serves until killed.
#[derive(clap::Args, Debug)]
pub struct CanopenArgs {
    /// Node ids as ID=AXIS (axis x or y); repeat for each drive on the bus.
    #[arg(long = "node", default_values_t = ["1=x".to_string(), "2=y".to_string()])]
    pub nodes: Vec<String>,
    /// EDS of the drives (default: the built-in config/canopen/drive.eds).
    #[arg(long)]
    pub eds: Option<PathBuf>,
    /// Also create a symlink to the port at this path (a stable name for clients).
    #[arg(long)]
    pub link: Option<PathBuf>,
    #[command(flatten)]
    pub rig: crate::rig_files::RigFiles,
    /// Simulated seconds per wall second, or `unconstrained` (a motion completes right
    /// after the frames that reported its start).
    #[arg(long, default_value = "1")]
    pub time_scale: String,
    /// Serve on this SocketCAN interface (vcan0, can0) instead of an SLCAN pty
    /// (Linux, cargo feature `socketcan`); prints `socketcan: IFACE`.
    #[arg(long)]
    pub socketcan: Option<String>,
    /// Write the executed path here (see `emulators grbl --trace`; SLCAN only): truth
    /// for tests.
    #[arg(long)]
    pub trace: Option<PathBuf>,
}

fn parse_node(s: &str) -> anyhow::Result<(u8, usize)> {
    let (id, axis) = s
        .split_once('=')
        .with_context(|| format!("--node `{s}`: expected ID=AXIS, like 1=x"))?;
    let id: u8 = id
        .trim()
        .parse()
        .with_context(|| format!("--node `{s}`: the id is 1..127"))?;
    anyhow::ensure!((1..=127).contains(&id), "--node `{s}`: the id is 1..127");
    let axis = match axis.trim().to_ascii_lowercase().as_str() {
        "x" => 0,
        "y" => 1,
        other => anyhow::bail!("--node `{s}`: axis `{other}`: the simulated machine has x and y"),
    };
    Ok((id, axis))
}

pub fn serve(args: CanopenArgs) -> anyhow::Result<()> {
    let clock = args
        .time_scale
        .parse::<world::Clock>()
        .context("--time-scale")?;
    let nodes = args
        .nodes
        .iter()
        .map(|s| parse_node(s))
        .collect::<anyhow::Result<Vec<_>>>()?;
    let eds = match &args.eds {
        Some(p) => (
            p.display().to_string(),
            std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?,
        ),
        None => (DRIVE_EDS_NAME.to_string(), DRIVE_EDS.to_string()),
    };
    let rig = args.rig.rig()?;
    let rig = Arc::new(Mutex::new(rig));
    let trace_rig = rig.clone();
    let set = DriveSet::new(rig, &DriveSetConfig { clock, nodes, eds }, 0.0)?;
    let ids = set.node_ids();
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let set = Arc::new(Mutex::new(set));
    if let Some(iface) = &args.socketcan {
        anyhow::ensure!(
            args.trace.is_none(),
            "--trace is for the SLCAN emulator only"
        );
        return serve_socketcan(&rt, set, iface, &ids);
    }
    rt.block_on(async move {
        let trace = match &args.trace {
            Some(path) => Some(
                crate::trace::TraceFile::start(trace_rig, path)
                    .with_context(|| format!("--trace {}", path.display()))?,
            ),
            None => None,
        };
        let mut pty =
            SlcanPty::spawn(set, args.link.as_deref()).context("creating the pseudo-terminal")?;
        println!("slcan: {}", pty.path());
        if let Some(l) = pty.link() {
            println!("link: {}", l.display());
        }
        println!(
            "nodes: {}",
            ids.iter().map(u8::to_string).collect::<Vec<_>>().join(",")
        );
        std::io::stdout().flush()?;
        tokio::select! {
            _ = pty.closed() => {}
            _ = tokio::signal::ctrl_c() => {}
        }
        if let Some(t) = trace {
            eprintln!("trace: {} rows", t.finish().await?);
        }
        Ok(())
    })
}

#[cfg(all(target_os = "linux", feature = "socketcan"))]
fn serve_socketcan(
    rt: &tokio::runtime::Runtime,
    set: super::SharedSet,
    iface: &str,
    ids: &[u8],
) -> anyhow::Result<()> {
    rt.block_on(async move {
        let mut port = super::socketcan::SocketCanPort::spawn(set, iface)
            .with_context(|| format!("opening SocketCAN interface {iface}"))?;
        println!("socketcan: {iface}");
        println!(
            "nodes: {}",
            ids.iter().map(u8::to_string).collect::<Vec<_>>().join(",")
        );
        std::io::stdout().flush()?;
        port.closed().await;
        Ok(())
    })
}

#[cfg(not(all(target_os = "linux", feature = "socketcan")))]
fn serve_socketcan(
    _rt: &tokio::runtime::Runtime,
    _set: super::SharedSet,
    iface: &str,
    _ids: &[u8],
) -> anyhow::Result<()> {
    anyhow::bail!("--socketcan {iface}: this build has no SocketCAN support (Linux, cargo feature `socketcan`)")
}
