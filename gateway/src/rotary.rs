//! `gateway rotary`: the A/C tilting table of source B: identification of its eight
//! location errors from measured ball centres, and the probing cycle on the simulated
//! 5-axis machine.

use crate::front::CliSink;
use clap::Subcommand;
use protocol::config::DataKind;
use rotary::MachineConstants;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(Subcommand)]
pub enum RotaryCmd {
    /// Identify the eight location errors from ball centres measured elsewhere (a CMM,
    /// as in the paper): a CSV `axis,step,angle_deg,ball,x_mm,y_mm,z_mm` of the C sweep
    /// (at A = 0) and the A sweep (at C = 0), machine coordinates.
    Identify {
        /// The centres file.
        #[arg(long)]
        centres: PathBuf,
        /// The machine constants (JSON: a_axis_y_mm, a_axis_z_mm, ac_offset_y_mm,
        /// ac_offset_z_mm, tool_length_mm); default: the built-in 340A-style mill.
        #[arg(long)]
        machine: Option<PathBuf>,
        /// Write the chart of centres and fitted circles (rotary-sweeps.svg and .png)
        /// into this folder.
        #[arg(long)]
        plot: Option<PathBuf>,
    },
    /// Rewrite a 5-axis program (X Y Z A C, absolute, mm) for the identified errors:
    /// every programmed point replaced by the command that puts the tool tip and
    /// direction back on it, feed moves split where the commands bend. Refuses (naming
    /// the line) arcs, inches, incremental moves, unknown axes and commands past the
    /// limits.
    Rewrite {
        /// The program (never overwritten).
        input: PathBuf,
        /// The errors (the JSON `gateway rotary identify` or `measure` writes).
        #[arg(long)]
        errors: PathBuf,
        #[arg(long)]
        out: PathBuf,
        /// The machine constants (JSON); default: those recorded in the errors file
        /// (else the built-in ones). Refused where they differ from the recorded ones.
        #[arg(long)]
        machine: Option<PathBuf>,
        #[command(flatten)]
        request: procedure::rotary::RotaryRewriteRequest,
    },
    /// Run the paper's measurement cycle with the touch probe on the simulated 5-axis
    /// machine (C in 12 steps of 30°, A in 6 steps of 15°, 6 points per ball, each
    /// touched fast, backed off and touched slowly), identify the errors, and check them
    /// and a compensated 5-axis program against the simulation's truth. Writes
    /// OUT/centres.csv, OUT/points.csv, OUT/errors.json and the sweep chart; a stopped
    /// cycle still writes what it measured.
    Measure {
        /// The rotary job (JSON: seed, errors, probe, plan, machine, speeds; all
        /// optional, defaults are the paper's table).
        #[arg(long)]
        config: PathBuf,
        #[arg(long)]
        out: PathBuf,
    },
}

pub fn run(cmd: RotaryCmd, json: bool) -> anyhow::Result<ExitCode> {
    match cmd {
        RotaryCmd::Identify {
            centres,
            machine,
            plot,
        } => {
            let request = procedure::rotary::RotaryIdentifyRequest {
                centres: protocol::config::read_kind(&centres, DataKind::Centres)?,
                centres_name: centres.display().to_string(),
                machine: machine
                    .as_deref()
                    .map(|p| load_constants(Some(p)))
                    .transpose()?,
            };
            let mut sink = CliSink::new("", true).inputs(&[&centres]);
            if let Some(dir) = &plot {
                sink = sink.into_folder(dir)?;
            }
            let wrote = plot
                .map(|d| format!("chart: {}", d.join("rotary-sweeps.svg").display()))
                .unwrap_or_default();
            crate::front::run_kind_then("rotary-identify", &request, &mut sink, json, &wrote, |f| f)
        }
        RotaryCmd::Measure { config, out } => {
            let request = procedure::request::RotaryRequest::default();
            let mut sink = CliSink::new("balls", json)
                .inputs(&[&config])
                .into_folder(&out)?;
            let wrote = format!("wrote {}", out.display());
            crate::front::run_kind_then("rotary", &request, &mut sink, json, &wrote, |f| {
                f.rotary_file(&config).out_folder(&out)
            })
        }
        RotaryCmd::Rewrite {
            input,
            errors,
            out,
            machine,
            request,
        } => rewrite(
            &input,
            &errors,
            &out,
            machine.as_deref(),
            request.force_machine,
            request.tolerance_um,
            json,
        ),
    }
}

/// `gateway rotary rewrite` (and `gateway rewrite --rotary`): the program, errors and
/// machine files read into the request, the program written to `out`.
pub fn rewrite(
    input: &Path,
    errors: &Path,
    out: &Path,
    machine: Option<&Path>,
    force_machine: bool,
    tolerance_um: f64,
    json: bool,
) -> anyhow::Result<ExitCode> {
    let request = procedure::rotary::RotaryRewriteRequest {
        program: procedure::rewrite::read_program(input).map_err(anyhow::Error::msg)?,
        program_name: input.display().to_string(),
        errors: procedure::rotary::read_errors_file(errors).map_err(anyhow::Error::msg)?,
        errors_name: errors.display().to_string(),
        machine: machine.map(|p| load_constants(Some(p))).transpose()?,
        force_machine,
        tolerance_um,
    };
    let mut sink = CliSink::new("", true)
        .inputs(&[input, errors])
        .artifact_to("program.nc", out.to_path_buf());
    let wrote = format!("wrote {}", out.display());
    crate::front::run_kind_then("rotary-rewrite", &request, &mut sink, json, &wrote, |f| f)
}

/// The machine constants from a JSON file, or the defaults.
pub fn load_constants(path: Option<&Path>) -> anyhow::Result<MachineConstants> {
    match path {
        None => Ok(MachineConstants::default()),
        Some(path) => procedure::rotary::read_machine_file(path).map_err(anyhow::Error::msg),
    }
}
