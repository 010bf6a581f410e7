//! `emulators`: stand-alone software devices and data generators.

use anyhow::Context;
use clap::{Parser, Subcommand};
use emulators::plate::{manufacture, PlateErrors};
use protocol::Board;
use std::path::PathBuf;

#[derive(Parser)]
#[command(name = "emulators", about = "Software devices for the gateway's buses, and test-data generators")]
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
}

fn main() -> anyhow::Result<()> {
    match Cli::parse().cmd {
        Cmd::MakeCertificate { board, seed, scale_ppm, bow_um, dot_sigma_um, out } => {
            let b = Board::load(&board)?;
            let mut nominal = Board::nominal(&b.name, b.pitch_mm, b.dot_diameter_mm, b.polarity, b.cols, b.rows, b.origin_mm);
            manufacture(&mut nominal, PlateErrors { scale_ppm, bow_um, dot_sigma_um }, seed);
            std::fs::write(&out, nominal.certificate_csv()).with_context(|| format!("writing {}", out.display()))?;
            println!("wrote {} ({} points)", out.display(), nominal.cols * nominal.rows);
        }
    }
    Ok(())
}
