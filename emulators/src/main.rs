//! `emulators`: stand-alone software devices and data generators.

use anyhow::Context;
use clap::{Parser, Subcommand};
use protocol::Board;
use std::path::PathBuf;
use world::plate::{manufacture, PlateErrors};

#[derive(Parser)]
#[command(
    name = "emulators",
    about = "Software devices for the gateway's buses, and test-data generators"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Draw a plate's manufacturing errors and write its certificate CSV (i,j,x_mm,y_mm).
    MakeCertificate {
        /// Board file (its geometry is used; an existing certificate is ignored).
        board: PathBuf,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        #[arg(long, default_value_t = PlateErrors::default().scale_ppm)]
        scale_ppm: f64,
        #[arg(long, default_value_t = PlateErrors::default().bow_um)]
        bow_um: f64,
        #[arg(long, default_value_t = PlateErrors::default().dot_sigma_um)]
        dot_sigma_um: f64,
        /// Output CSV path.
        #[arg(long, short)]
        out: PathBuf,
    },
    /// Serve a GRBL 1.1 controller on a new pseudo-terminal, driving the simulated
    /// machine; prints the port path (`/dev/pts/N`) and serves until killed.
    Grbl {
        /// The rig (the board and camera are not used by the controller itself).
        #[command(flatten)]
        rig: emulators::rig_files::RigFiles,
        /// Also create a symlink to the port at this path (stable name for senders).
        #[arg(long)]
        link: Option<PathBuf>,
        /// Simulated seconds per wall second, or `unconstrained` (motion completes as
        /// soon as anything depends on it).
        #[arg(long, default_value = "1")]
        time_scale: String,
        /// Write the executed path here (CSV `t_s,cmd_x_mm,cmd_y_mm,true_x_mm,true_y_mm`,
        /// a row every 0.05 mm of motion and at every move's end): truth for tests.
        #[arg(long)]
        trace: Option<PathBuf>,
    },
    /// Serve Modbus positioning drives (a profile's register map, several unit ids)
    /// driving the simulated machine, over TCP and/or RTU on a new pseudo-terminal;
    /// prints the address or port path and serves until killed.
    Modbus(emulators::modbus::cli::ModbusArgs),
    /// Serve CiA 402 drive nodes (one per machine axis) behind an SLCAN adapter on a
    /// new pseudo-terminal, driving the simulated machine; prints `slcan: /dev/pts/N`.
    Canopen(emulators::canopen::cli::CanopenArgs),
    /// Serve a GigE Vision camera rendering the board at the simulated machine's pose
    /// (GVCP on 127.0.0.1:3956 by default), optionally with a stage emulator (`--stage
    /// grbl|modbus|canopen`) on the same machine; prints `gige: ADDR:PORT` and the
    /// stage's port.
    #[command(visible_alias = "rig")]
    Gige(emulators::gige::cli::GigeArgs),
    /// Serve a closed controller's tape port (DNC drip-feed: DC1/DC3, `%` tapes, ISO
    /// code, Fanuc-dialect programs) on a new pseudo-terminal, driving the simulated
    /// machine; prints `dnc: /dev/pts/N`. Panel on standard input: `reset`, `start`.
    Dnc(emulators::dnc::cli::DncArgs),
}

fn serve_grbl(
    rig: emulators::rig_files::RigFiles,
    link: Option<PathBuf>,
    time_scale: String,
    trace: Option<PathBuf>,
) -> anyhow::Result<()> {
    use emulators::grbl::{GrblConfig, GrblDevice, GrblPty};
    use std::io::Write;
    let clock = time_scale.parse::<world::Clock>().context("--time-scale")?;
    let rig = rig.rig()?;
    let rig = std::sync::Arc::new(std::sync::Mutex::new(rig));
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    rt.block_on(async move {
        let trace = match &trace {
            Some(path) => Some(
                emulators::trace::TraceFile::start(rig.clone(), path)
                    .with_context(|| format!("--trace {}", path.display()))?,
            ),
            None => None,
        };
        let dev = GrblDevice::new(
            rig,
            GrblConfig {
                clock,
                ..Default::default()
            },
        );
        let mut pty =
            GrblPty::spawn(dev, link.as_deref()).context("creating the pseudo-terminal")?;
        println!("grbl: {}", pty.path());
        if let Some(l) = pty.link() {
            println!("link: {}", l.display());
        }
        std::io::stdout().flush()?;
        tokio::select! {
            _ = pty.closed() => {}
            _ = tokio::signal::ctrl_c() => {}
        }
        if let Some(t) = trace {
            let rows = t.finish().await?;
            eprintln!("trace: {rows} rows");
        }
        Ok(())
    })
}

fn main() -> anyhow::Result<()> {
    match Cli::parse().cmd {
        Cmd::Modbus(args) => emulators::modbus::cli::serve(args)?,
        Cmd::Canopen(args) => emulators::canopen::cli::serve(args)?,
        Cmd::Gige(args) => emulators::gige::cli::serve(args)?,
        Cmd::Dnc(args) => emulators::dnc::cli::serve(args)?,
        Cmd::Grbl {
            rig,
            link,
            time_scale,
            trace,
        } => serve_grbl(rig, link, time_scale, trace)?,
        Cmd::MakeCertificate {
            board,
            seed,
            scale_ppm,
            bow_um,
            dot_sigma_um,
            out,
        } => {
            let b = Board::load(&board)?;
            let mut nominal = Board::nominal(
                &b.name,
                b.pitch_mm,
                b.dot_diameter_mm,
                b.polarity,
                b.cols,
                b.rows,
                b.origin_mm,
            );
            manufacture(
                &mut nominal,
                PlateErrors {
                    scale_ppm,
                    bow_um,
                    dot_sigma_um,
                },
                seed,
            );
            std::fs::write(&out, nominal.certificate_csv())
                .with_context(|| format!("writing {}", out.display()))?;
            println!(
                "wrote {} ({} points)",
                out.display(),
                nominal.cols * nominal.rows
            );
        }
    }
    Ok(())
}
