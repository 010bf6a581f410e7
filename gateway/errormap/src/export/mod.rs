//! The map as a controller's own compensation table, for controllers that compensate by
//! themselves: each format holds part of what the map knows, and each writer says what is
//! lost (and refuses when the loss exceeds the tolerance).
//!
//! * LinuxCNC per-joint `COMP_FILE` (`[JOINT_n]COMP_FILE_TYPE = 0`): one line per entry,
//!   `nominal forward reverse`, the actual positions (machine units, mm here) the joint
//!   reaches when commanded `nominal` moving in + and in -; LinuxCNC interpolates linearly
//!   between at most 256 entries (`EMCMOT_COMP_SIZE`) and moves the motor so the joint
//!   lands on nominal. It depends on the joint's own position only: the error of X that
//!   changes with Y (squareness, yaw) and X's straightness seen in Y are not held.
//!   Worked example: where X commanded to 50 mm really stops 12 um further going up and
//!   4 um going down, the line reads `50.000000 50.012000 50.004000`.
//! * Beckhoff/ISG plane compensation (`kw.crosscomp2`, TwinCAT CNC): per slave axis a
//!   table of corrections over a regular grid of the two master axes (X, Y), in 0.1 um,
//!   added to the slave's command, so a correction is minus the error. One table for
//!   both directions: the backlash (half the forward/reverse difference) is not held.
//! * A plain CSV of the model on the map's grid, every quantity in both directions.
//!
//! The industrial controllers' own tables (Siemens EEC/CEC, Fanuc pitch error,
//! Heidenhain, Haas) are in their modules; [`controller`] holds what they share.

pub mod controller;
pub mod fanuc;
pub mod haas;
pub mod heidenhain;
pub mod siemens;

pub use controller::{ControllerTables, Fit, ValueSign};
pub use fanuc::{fanuc_pitch, FanucOptions, FanucSection, TvCheck};
pub use haas::haas;
pub use heidenhain::{heidenhain_64, heidenhain_com};
pub use siemens::{siemens, CecMultiplier, SiemensOptions};

use crate::{Approach, Direction, MapModel, ModelError};
use std::fmt::Write;

/// LinuxCNC's `EMCMOT_COMP_SIZE`: entries per joint.
pub const LINUXCNC_MAX_ENTRIES: usize = 256;

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ExportError {
    #[error("{format}: the table differs from the map by up to {got_um:.2} um at {at_mm:.3} mm, beyond the tolerance of {tolerance_um:.2} um ({why})")]
    BeyondTolerance {
        format: &'static str,
        got_um: f64,
        tolerance_um: f64,
        at_mm: f64,
        why: String,
    },
    #[error("{0}")]
    Model(#[from] ModelError),
    #[error("{0}")]
    Options(String),
}

/// One joint's table and what it leaves out.
#[derive(Debug, Clone, PartialEq)]
pub struct JointTable {
    /// The `COMP_FILE` text.
    pub text: String,
    pub entries: usize,
    /// Largest difference between LinuxCNC's linear interpolation of the table and the
    /// map along the line the table was taken on, um.
    pub interpolation_error_um: f64,
    /// Largest part of this joint's error that depends on the other axis (the table
    /// cannot hold it), um.
    pub cross_terms_um: f64,
    /// The other axis's position the table was taken at, mm.
    pub taken_at_mm: f64,
}

fn sample(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    (0..n)
        .map(|k| lo + (hi - lo) * k as f64 / (n - 1) as f64)
        .collect()
}

fn dir(a: Approach) -> Direction {
    Direction { x: a, y: a }
}

/// The LinuxCNC table of joint `axis` (0 = X, 1 = Y), taken along the line through the
/// map's reference point, with `entries` (2..=256) evenly spaced over the map.
pub fn linuxcnc_joint(
    model: &MapModel,
    axis: usize,
    entries: usize,
    tolerance_um: f64,
) -> Result<JointTable, ExportError> {
    if axis > 1 {
        return Err(ExportError::Options(format!(
            "axis {axis}: the map has X (0) and Y (1)"
        )));
    }
    if !(2..=LINUXCNC_MAX_ENTRIES).contains(&entries) {
        return Err(ExportError::Options(format!(
            "{entries} entries: LinuxCNC holds 2 to {LINUXCNC_MAX_ENTRIES} per joint"
        )));
    }
    let (lo, hi) = model.extent();
    let other = 1 - axis;
    let at = model.map().reference_mm[other];
    let point = |s: f64, t: f64| {
        let mut p = [0.0; 2];
        p[axis] = s;
        p[other] = t;
        p
    };
    let error = |s: f64, t: f64, a: Approach| -> Result<f64, ModelError> {
        Ok(model.tool_error_um(point(s, t), dir(a))?[axis])
    };
    let nominal = sample(lo[axis], hi[axis], entries);
    // LinuxCNC refuses a table whose nominals do not strictly increase (through its
    // error channel, after loading nothing): check them as written, 6 decimals.
    let written: Vec<String> = nominal.iter().map(|s| format!("{s:.6}")).collect();
    if let Some(k) = written
        .windows(2)
        .position(|w| w[1].parse::<f64>().ok() <= w[0].parse::<f64>().ok())
    {
        return Err(ExportError::Options(format!(
            "{entries} entries over {:.6} mm: entries {k} and {} are both written {} mm (LinuxCNC needs strictly increasing nominals at 1 nm): fewer entries",
            hi[axis] - lo[axis],
            k + 1,
            written[k]
        )));
    }
    // No header or comment line: LinuxCNC would silently load nothing.
    let mut text = String::new();
    let mut table = Vec::with_capacity(entries);
    for (&s, w) in nominal.iter().zip(&written) {
        let f = s + error(s, at, Approach::Forward)? / 1000.0;
        let r = s + error(s, at, Approach::Reverse)? / 1000.0;
        let _ = writeln!(text, "{w} {f:.6} {r:.6}");
        table.push((s, f, r));
    }
    // LinuxCNC's linear interpolation against the map, every 0.05 mm of the line.
    let n = (((hi[axis] - lo[axis]) / 0.05).ceil() as usize).max(2) + 1;
    let (mut worst, mut worst_at) = (0.0f64, lo[axis]);
    for s in sample(lo[axis], hi[axis], n) {
        let k = table
            .windows(2)
            .position(|w| s <= w[1].0)
            .unwrap_or(table.len() - 2);
        let (a, b) = (table[k], table[k + 1]);
        let t = (s - a.0) / (b.0 - a.0);
        for (ta, tb, side) in [(a.1, b.1, Approach::Forward), (a.2, b.2, Approach::Reverse)] {
            let interp_um = (ta + (tb - ta) * t - s) * 1000.0;
            let d = (interp_um - error(s, at, side)?).abs();
            if d > worst {
                (worst, worst_at) = (d, s);
            }
        }
    }
    if worst > tolerance_um {
        return Err(ExportError::BeyondTolerance {
            format: "LinuxCNC COMP_FILE",
            got_um: worst,
            tolerance_um,
            at_mm: worst_at,
            why: format!("{entries} entries cannot follow the map's short-period error; LinuxCNC holds at most {LINUXCNC_MAX_ENTRIES}"),
        });
    }
    // What depends on the other axis: this joint's error across the map minus its value
    // on the table's line.
    let mut cross = 0.0f64;
    for s in sample(lo[axis], hi[axis], 41) {
        let on_line = error(s, at, Approach::Forward)?;
        for t in sample(lo[other], hi[other], 31) {
            cross = cross.max((error(s, t, Approach::Forward)? - on_line).abs());
        }
    }
    Ok(JointTable {
        text,
        entries,
        interpolation_error_um: worst,
        cross_terms_um: cross,
        taken_at_mm: at,
    })
}

/// One slave axis's plane compensation list and what it leaves out.
#[derive(Debug, Clone, PartialEq)]
pub struct PlaneTable {
    pub text: String,
    pub points: usize,
    /// Largest difference between the table (bilinear between its points) and the map
    /// (mean of the two directions), um.
    pub interpolation_error_um: f64,
    /// Half the largest forward/reverse difference: the backlash the one table loses, um.
    pub backlash_lost_um: f64,
}

/// The Beckhoff/ISG plane compensation list of slave `axis` (0 = X, 1 = Y; logical axis
/// numbers 1 and 2), master 1 = X, master 2 = Y, on a square grid of `interval_mm`.
pub fn beckhoff_plane(
    model: &MapModel,
    axis: usize,
    interval_mm: f64,
    tolerance_um: f64,
) -> Result<PlaneTable, ExportError> {
    if axis > 1 {
        return Err(ExportError::Options(format!(
            "axis {axis}: the map has X (0) and Y (1)"
        )));
    }
    if !(interval_mm.is_finite() && interval_mm >= 0.1) {
        return Err(ExportError::Options(format!(
            "interval {interval_mm} mm: at least 0.1 mm"
        )));
    }
    let (lo, hi) = model.extent();
    let last = |k: usize| ((hi[k] - lo[k]) / interval_mm).floor() as usize;
    let (l1, l2) = (last(0), last(1));
    if l1 < 1 || l2 < 1 {
        return Err(ExportError::Options(format!(
            "interval {interval_mm} mm: the map ({:.1} x {:.1} mm) needs at least two points per axis",
            hi[0] - lo[0],
            hi[1] - lo[1]
        )));
    }
    let name = ["X", "Y"][axis];
    let units = |mm: f64| (mm * 10_000.0).round() as i64;
    let mean_error = |p: [f64; 2]| -> Result<(f64, f64), ModelError> {
        let f = model.tool_error_um(p, dir(Approach::Forward))?[axis];
        let r = model.tool_error_um(p, dir(Approach::Reverse))?[axis];
        Ok(((f + r) / 2.0, (f - r).abs() / 2.0))
    };
    let mut text = String::new();
    let _ = writeln!(
        text,
        "# Plane compensation of axis {name} from the gateway's error map"
    );
    let _ = writeln!(text, "# {}", model.map().identity.machine);
    let _ = writeln!(
        text,
        "# corrections in 0.1 um, added to the {name} command (minus the error)"
    );
    let _ = writeln!(
        text,
        "kopf.achs_nr                               {}",
        axis + 1
    );
    let _ = writeln!(text, "kopf.log_achs_name                         {name}");
    let _ = writeln!(
        text,
        "kw.crosscomp2.max_points                   {}",
        (l1 + 1) * (l2 + 1)
    );
    let _ = writeln!(
        text,
        "kw.crosscomp2.interval                     {}",
        units(interval_mm)
    );
    let _ = writeln!(text, "kw.crosscomp2.last_index_master1           {l1}");
    let _ = writeln!(text, "kw.crosscomp2.last_index_master2           {l2}");
    let _ = writeln!(
        text,
        "kw.crosscomp2.start_position_master1       {}",
        units(lo[0])
    );
    let _ = writeln!(
        text,
        "kw.crosscomp2.start_position_master2       {}",
        units(lo[1])
    );
    let _ = writeln!(text, "kw.crosscomp2.master1_ax_nr                1");
    let _ = writeln!(text, "kw.crosscomp2.master2_ax_nr                2");
    let mut grid = vec![vec![0.0; l1 + 1]; l2 + 1];
    let mut backlash = 0.0f64;
    for (j, row) in grid.iter_mut().enumerate() {
        for (i, cell) in row.iter_mut().enumerate() {
            let p = [
                lo[0] + i as f64 * interval_mm,
                lo[1] + j as f64 * interval_mm,
            ];
            let (mean, half) = mean_error(p)?;
            backlash = backlash.max(half);
            // Rounded to the 0.1 um the list holds.
            *cell = (-mean * 10.0).round() / 10.0;
            let _ = writeln!(
                text,
                "kw.crosscomp2.table[{j:3}][{i:4}].correction {}",
                (-mean * 10.0).round() as i64
            );
        }
    }
    // The table bilinear between its points against the map, at the middle of every cell
    // and of every edge (where interpolation strays most).
    let mut worst = 0.0f64;
    let mut worst_at = lo[0];
    for j in 0..l2 {
        for i in 0..l1 {
            for (u, v) in [(0.5, 0.5), (0.5, 0.0), (0.0, 0.5)] {
                let p = [
                    lo[0] + (i as f64 + u) * interval_mm,
                    lo[1] + (j as f64 + v) * interval_mm,
                ];
                let table = -((1.0 - u) * (1.0 - v) * grid[j][i]
                    + u * (1.0 - v) * grid[j][i + 1]
                    + (1.0 - u) * v * grid[j + 1][i]
                    + u * v * grid[j + 1][i + 1]);
                let d = (table - mean_error(p)?.0).abs();
                if d > worst {
                    (worst, worst_at) = (d, p[axis]);
                }
            }
        }
    }
    if worst > tolerance_um {
        return Err(ExportError::BeyondTolerance {
            format: "Beckhoff plane compensation",
            got_um: worst,
            tolerance_um,
            at_mm: worst_at,
            why: format!(
                "a {interval_mm} mm grid is too coarse for the map; try a smaller --interval-mm"
            ),
        });
    }
    Ok(PlaneTable {
        text,
        points: (l1 + 1) * (l2 + 1),
        interpolation_error_um: worst,
        backlash_lost_um: backlash,
    })
}

/// The model on the map's own grid: one row per node, both directions.
pub fn plain_csv(model: &MapModel) -> Result<String, ExportError> {
    let g = &model.map().grid;
    let mut out = String::from(
        "x_mm,y_mm,ex_forward_um,ey_forward_um,yaw_forward_urad,ex_reverse_um,ey_reverse_um,yaw_reverse_urad\n",
    );
    for &y in &g.ys {
        for &x in &g.xs {
            let mut row = format!("{x:.4},{y:.4}");
            for a in [Approach::Forward, Approach::Reverse] {
                let e = model.camera_error_um([x, y], dir(a))?;
                let yaw = model.yaw_urad([x, y], dir(a))?;
                let _ = write!(row, ",{:.4},{:.4},{:.3}", e[0], e[1], yaw);
            }
            out.push_str(&row);
            out.push('\n');
        }
    }
    Ok(out)
}
