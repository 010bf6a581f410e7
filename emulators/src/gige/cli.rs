//! The `emulators gige` command (alias `rig`): the GigE Vision camera on a simulated
//! machine, optionally with a stage emulator (GRBL on a pseudo-terminal, Modbus drives
//! on TCP, CiA 402 drives behind an SLCAN adapter on a pseudo-terminal) driving the same
//! machine, so that a separate gateway process runs the whole loop over real links.
//! Prints `gige: ADDR:PORT` (and `grbl: /dev/pts/N`, `modbus tcp: ADDR:PORT` or
//! `slcan: /dev/pts/N`) and serves until killed.

use super::device::GigeConfig;
use super::server::{GigeCameraServer, GigeServerOptions};
use anyhow::Context;
use std::io::Write;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};

#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum StageKind {
    None,
    Grbl,
    Modbus,
    Canopen,
}

/// Serve a GigE Vision camera (and optionally a stage) on one simulated machine.
#[derive(clap::Args, Debug)]
pub struct GigeArgs {
    /// GVCP address. Port 3956 is where Aravis discovery looks (`arv-tool-0.8 -a
    /// 127.0.0.1`); port 0 picks a free port (printed), reachable by address only.
    #[arg(long, default_value = "127.0.0.1:3956")]
    pub bind: SocketAddr,
    /// Do not listen for discovery broadcasts (255.255.255.255:<port>).
    #[arg(long)]
    pub no_broadcast: bool,
    /// Serial number (device id `XYGateway-SimMono-<serial>`).
    #[arg(long, default_value = "SIM0001")]
    pub serial: String,
    /// User-defined name (another name to open the camera by).
    #[arg(long, default_value = "")]
    pub user_name: String,
    /// Continuous-mode frame rate (frames per second) the camera starts with.
    #[arg(long, default_value_t = 10.0)]
    pub frame_rate: f32,
    /// Packet-loss injection: drop every Nth payload packet of each frame (resends
    /// are delivered).
    #[arg(long)]
    pub drop_every: Option<u32>,
    /// Drop the resent packets too (frames can then only arrive incomplete).
    #[arg(long)]
    pub loss_on_resend: bool,
    /// Serve the GenICam XML zipped, as many real cameras do.
    #[arg(long)]
    pub zip_xml: bool,
    /// Also host a stage emulator on the same machine (GRBL on a pseudo-terminal, Modbus
    /// drives on TCP, CiA 402 drives behind SLCAN on a pseudo-terminal).
    #[arg(long, value_enum, default_value = "none")]
    pub stage: StageKind,
    /// GRBL or CANopen: also create a symlink to the port at this path.
    #[arg(long)]
    pub link: Option<PathBuf>,
    /// Modbus: TCP address of the drives (port 0: a free port, printed).
    #[arg(long, default_value = "127.0.0.1:0")]
    pub modbus_tcp: SocketAddr,
    /// Modbus: drive profile.
    #[arg(long, default_value = "config/drives/generic.toml")]
    pub profile: PathBuf,
    /// Simulated seconds per wall second of the stage, or `unconstrained`.
    #[arg(long, default_value = "1")]
    pub time_scale: String,
    #[command(flatten)]
    pub rig: crate::rig_files::RigFiles,
}

pub fn serve(a: GigeArgs) -> anyhow::Result<()> {
    let clock = a
        .time_scale
        .parse::<world::Clock>()
        .context("--time-scale")?;
    let rig = a.rig.rig()?;
    let rig = Arc::new(Mutex::new(rig));
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    rt.block_on(async move {
        let cam = GigeCameraServer::spawn(
            rig.clone(),
            GigeServerOptions {
                bind: a.bind,
                broadcast: !a.no_broadcast && a.bind.port() != 0,
                config: GigeConfig {
                    serial: a.serial.clone(),
                    user_name: a.user_name.clone(),
                    frame_rate_hz: a.frame_rate,
                    drop_every: a.drop_every,
                    loss_on_resend: a.loss_on_resend,
                    zip_xml: a.zip_xml,
                    clock,
                    ..Default::default()
                },
            },
        )
        .await
        .with_context(|| format!("binding the GVCP socket on {}", a.bind))?;
        println!("gige: {}", cam.control_addr());
        println!("device id: XYGateway-SimMono-{}", a.serial);
        let mut grbl = None;
        let mut _modbus = None;
        let mut slcan = None;
        match a.stage {
            StageKind::None => {}
            StageKind::Grbl => {
                use crate::grbl::{GrblConfig, GrblDevice, GrblPty};
                let dev = GrblDevice::new(
                    rig.clone(),
                    GrblConfig {
                        clock,
                        ..Default::default()
                    },
                );
                let pty = GrblPty::spawn(dev, a.link.as_deref())
                    .context("creating the pseudo-terminal")?;
                println!("grbl: {}", pty.path());
                if let Some(l) = pty.link() {
                    println!("link: {}", l.display());
                }
                grbl = Some(pty);
            }
            StageKind::Modbus => {
                use crate::modbus::device::{DriveSet, MachineAxis};
                use crate::modbus::server::{ModbusDevice, ModbusTcp};
                let profile = Arc::new(protocol::modbus::DriveProfile::load(&a.profile)?);
                let units = [(1u8, MachineAxis::X), (2u8, MachineAxis::Y)];
                let device = ModbusDevice::new(DriveSet::new(rig.clone(), profile, &units, clock));
                let s = ModbusTcp::bind(device, a.modbus_tcp)
                    .await
                    .with_context(|| format!("listening on {}", a.modbus_tcp))?;
                println!("modbus tcp: {} (units 1=x, 2=y)", s.local_addr());
                _modbus = Some(s);
            }
            StageKind::Canopen => {
                use crate::canopen::drives::{DriveSet, DriveSetConfig, DRIVE_EDS, DRIVE_EDS_NAME};
                let cfg = DriveSetConfig {
                    clock,
                    nodes: vec![(1, 0), (2, 1)],
                    eds: (DRIVE_EDS_NAME.to_string(), DRIVE_EDS.to_string()),
                };
                let set = DriveSet::new(rig.clone(), &cfg, 0.0)?;
                let pty =
                    crate::canopen::SlcanPty::spawn(Arc::new(Mutex::new(set)), a.link.as_deref())
                        .context("creating the pseudo-terminal")?;
                println!("slcan: {} (nodes 1=x, 2=y)", pty.path());
                if let Some(l) = pty.link() {
                    println!("link: {}", l.display());
                }
                slcan = Some(pty);
            }
        }
        std::io::stdout().flush()?;
        match (&mut grbl, &mut slcan) {
            (Some(p), _) => p.closed().await,
            (None, Some(p)) => p.closed().await,
            _ => std::future::pending::<()>().await,
        }
        drop(cam);
        Ok(())
    })
}
