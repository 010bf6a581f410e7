//! The `emulators modbus` command: Modbus drives on the simulated machine, served
//! stand-alone over TCP and/or RTU on a pseudo-terminal until killed.

use super::device::{DriveSet, MachineAxis};
use super::server::{Fault, FaultRule, ModbusDevice, ModbusRtu, ModbusTcp};
use anyhow::Context;
use protocol::modbus::DriveProfile;
use std::io::Write;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// Serve Modbus positioning drives driving the simulated machine: over TCP (prints
/// `modbus tcp: ADDR:PORT`) and/or RTU on a new pseudo-terminal (prints
/// `modbus rtu: /dev/pts/N`), until killed.
#[derive(clap::Args, Debug)]
pub struct ModbusArgs {
    /// Serve Modbus TCP on this address (port 0: a free port, printed).
    #[arg(long)]
    pub tcp: Option<String>,
    /// Serve Modbus RTU on a new pseudo-terminal.
    #[arg(long)]
    pub rtu: bool,
    /// Also create a symlink to the RTU port at this path.
    #[arg(long)]
    pub link: Option<PathBuf>,
    /// Drive profile (register map).
    #[arg(long, default_value = "config/drives/generic.toml")]
    pub profile: PathBuf,
    /// Units as ID=AXIS (axis x or y); repeat for several drives on the line.
    #[arg(long = "unit", default_values_t = ["1=x".to_string(), "2=y".to_string()])]
    pub units: Vec<String>,
    #[command(flatten)]
    pub rig: crate::rig_files::RigFiles,
    /// Simulated seconds per wall second, or `unconstrained` (motion completes right
    /// after a status read has reported it).
    #[arg(long, default_value = "1")]
    pub time_scale: String,
    /// Fault injection: drop the reply to every Nth request (executed, not answered).
    #[arg(long)]
    pub drop_reply_every: Option<u64>,
    /// Fault injection: lose every Nth request (neither executed nor answered).
    #[arg(long)]
    pub drop_request_every: Option<u64>,
    /// Fault injection: corrupt the reply to every Nth request (RTU: bad CRC; TCP:
    /// wrong transaction id).
    #[arg(long)]
    pub corrupt_every: Option<u64>,
    /// Fault injection: delay the reply to every Nth request by --slow-ms.
    #[arg(long)]
    pub slow_every: Option<u64>,
    #[arg(long, default_value_t = 1000)]
    pub slow_ms: u64,
    /// Write the executed path here (see `emulators grbl --trace`): truth for tests.
    #[arg(long)]
    pub trace: Option<PathBuf>,
    /// Apply the faults only to requests with this function code (e.g. 16).
    #[arg(long)]
    pub fault_function: Option<u8>,
}

fn parse_unit(s: &str) -> anyhow::Result<(u8, MachineAxis)> {
    let bad = || {
        anyhow::anyhow!("--unit `{s}`: expected ID=AXIS with ID 1..=247 and AXIS x or y, like 1=x")
    };
    let (id, axis) = s.split_once('=').ok_or_else(bad)?;
    let id: u8 = id.trim().parse().map_err(|_| bad())?;
    anyhow::ensure!((1..=247).contains(&id), bad());
    let axis = match axis.trim().to_ascii_lowercase().as_str() {
        "x" => MachineAxis::X,
        "y" => MachineAxis::Y,
        _ => return Err(bad()),
    };
    Ok((id, axis))
}

/// The fault rules the flags ask for.
pub fn faults(a: &ModbusArgs) -> Vec<FaultRule> {
    let mut v = Vec::new();
    let mut add = |n: Option<u64>, f: Fault| {
        if let Some(n) = n {
            let mut r = FaultRule::new(f).every(n);
            if let Some(fc) = a.fault_function {
                r = r.on_function(fc);
            }
            v.push(r);
        }
    };
    add(a.drop_request_every, Fault::DropRequest);
    add(a.drop_reply_every, Fault::DropReply);
    add(a.corrupt_every, Fault::CorruptReply);
    add(
        a.slow_every,
        Fault::SlowReply(Duration::from_millis(a.slow_ms)),
    );
    v
}

pub fn serve(a: ModbusArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        a.tcp.is_some() || a.rtu,
        "give --tcp ADDR:PORT and/or --rtu"
    );
    let clock = a
        .time_scale
        .parse::<world::Clock>()
        .context("--time-scale")?;
    let mut units = Vec::new();
    for u in &a.units {
        let (id, axis) = parse_unit(u)?;
        anyhow::ensure!(
            !units.iter().any(|(i, _)| *i == id),
            "--unit {id} is given twice"
        );
        units.push((id, axis));
    }
    let profile = Arc::new(DriveProfile::load(&a.profile)?);
    let tcp_addr = match &a.tcp {
        Some(t) => Some(
            t.parse::<std::net::SocketAddr>()
                .with_context(|| format!("--tcp `{t}`: expected ADDR:PORT"))?,
        ),
        None => None,
    };
    let rig = a.rig.rig()?;
    let rig = Arc::new(Mutex::new(rig));
    let trace_rig = rig.clone();
    let device = ModbusDevice::new(DriveSet::new(rig, profile.clone(), &units, clock));
    device.set_faults(faults(&a));
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    rt.block_on(async move {
        let trace = match &a.trace {
            Some(path) => Some(
                crate::trace::TraceFile::start(trace_rig, path)
                    .with_context(|| format!("--trace {}", path.display()))?,
            ),
            None => None,
        };
        let _tcp = match tcp_addr {
            Some(addr) => {
                let s = ModbusTcp::bind(device.clone(), addr)
                    .await
                    .with_context(|| format!("listening on {addr}"))?;
                println!("modbus tcp: {}", s.local_addr());
                Some(s)
            }
            None => None,
        };
        let mut rtu = if a.rtu {
            let r = ModbusRtu::spawn(device.clone(), a.link.as_deref())
                .context("creating the pseudo-terminal")?;
            println!("modbus rtu: {}", r.path());
            if let Some(l) = r.link() {
                println!("link: {}", l.display());
            }
            Some(r)
        } else {
            None
        };
        let ids: Vec<String> = units.iter().map(|(i, ax)| format!("{i}={ax:?}")).collect();
        println!(
            "profile: {} ({}), units {}",
            profile.name,
            a.profile.display(),
            ids.join(", ")
        );
        std::io::stdout().flush()?;
        let closed = async {
            match &mut rtu {
                Some(r) => r.closed().await,
                None => std::future::pending::<()>().await,
            }
        };
        tokio::select! {
            _ = closed => {}
            _ = tokio::signal::ctrl_c() => {}
        }
        if let Some(t) = trace {
            eprintln!("trace: {} rows", t.finish().await?);
        }
        Ok(())
    })
}
