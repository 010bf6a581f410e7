//! An emulated 3-axis machining centre with 21 geometric errors (truth for tests only),
//! and a simulated measurement campaign that writes the instrument files a shop would.
//!
//! The machine follows the conventions of the `volumetric` crate (command `+q` moves the
//! tool `+q` relative to the workpiece; workpiece carriages move by `-q`; each carriage's
//! error motions are its own, in its frame at its origin; squareness tilts Y about Z by
//! E_C0Y and Z by E_B0Z about Y then E_A0Z about X), but computes the tool point with its
//! own chain code: the tool and workpiece frames in R separately, a general 4 x 4 inverse.
//!
//! Default: structure XYFZ, travel 500 x 400 x 400 mm (the paper's TC500). Each error
//! motion is a seeded smooth function, zero at position 0: positioning a linear scale
//! error plus waves (tens of µm over the travel), straightness a few to ten µm, angles
//! tens of µrad; squareness tens of µrad.
//!
//! # Campaign files (see `protocol::volumetric` for the grammar)
//!
//! Each axis is measured alone (the other axes at 0), along the line through the
//! reference point (optics at zero tool and workpiece offset), every 25 mm, in 3 runs.
//! Values are the tool's error relative to the workpiece as the instrument reads it:
//! - `laser_X.csv`: `run,position_mm,E_XX_um,E_YX_um,E_ZX_um,E_BX_urad,E_CX_urad`
//!   (Y: `E_XY,E_YY,E_ZY,E_AY,E_CY`; Z: `E_XZ,E_YZ,E_ZZ,E_AZ,E_BZ`); straightness is
//!   relative to the machine's reference axes (not detrended). Header keys:
//!   `instrument: laser interferometer`, `axis`, `uncertainty_um`, `uncertainty_urad`.
//! - `level_X.csv`: `run,position_mm,E_AX_urad` (Y: E_BY, Z: E_CZ); header `instrument:
//!   electronic level` (for Z, whose roll a level cannot see, angular optics),
//!   `uncertainty_urad`.
//!   The straightness columns have each run's least-squares line removed and read 0 at
//!   position 0, as the instrument's software gives them (the optics are aligned to the
//!   line of motion, so the slope is not measured); header `straightness: ...`.
//! - `ballbar_XY.csv`, `ballbar_XZ.csv`, `ballbar_YZ.csv`: `run,angle_deg,deviation_um`,
//!   the bar's length deviation every degree on a 150 mm circle about (250, 200, 200) mm,
//!   two runs; header `plane`, `radius_mm`, `centre_mm` (three numbers), `uncertainty_um`
//!   (0.5; noise 0.1 µm; pivot set within 3 µm).
//! - `camera.csv` (written by [`VolumetricMachine::camera_campaign`], not `campaign`):
//!   `run,point,x_mm,y_mm,z_mm,board_x_mm,board_y_mm`, the board coordinates of the image
//!   centre with the board on risers at each height of the plan.
//!
//! The truth's straightness functions are about the mean lines of motion (ISO 230-1:
//! X's line is the x direction, the other lines' angles are the squareness constants),
//! so the squareness the ball-bar finds is the machine's.
//!
//! Noise is Gaussian: 0.3 µm and 0.3 µrad standard deviation, stated uncertainty 1 µm
//! and 1 µrad.

use crate::camera::{CameraModel, CameraPose};
use crate::render::{render, RenderedFrame};
use crate::rng::Rng;
use kinematics::{exact_error, translation, Htm};
use nalgebra::Vector4;
use protocol::volumetric::Structure;
use protocol::Board;

const TAU: f64 = std::f64::consts::TAU;

/// A smooth error function on [0, L]: `lin·u + Σ a_k (sin(2π f_k u + φ_k) − sin φ_k)`.
#[derive(Debug, Clone)]
struct ErrorFn {
    length: f64,
    lin: f64,
    waves: [(f64, f64, f64); 3],
}

impl ErrorFn {
    fn random(rng: &mut Rng, length: f64, lin: f64, amp: f64) -> ErrorFn {
        let lin = rng.range(-lin, lin);
        let waves = std::array::from_fn(|k| {
            (
                rng.range(-amp, amp) / (k + 1) as f64,
                rng.range(0.3, 1.5) * (k + 1) as f64,
                rng.range(0.0, TAU),
            )
        });
        ErrorFn { length, lin, waves }
    }

    fn at(&self, q: f64) -> f64 {
        let u = q / self.length;
        self.lin * u
            + self
                .waves
                .iter()
                .map(|&(a, f, p)| a * ((TAU * f * u + p).sin() - p.sin()))
                .sum::<f64>()
    }
}

/// Least-squares slope of (x, y) pairs.
fn lsq_slope(points: impl Iterator<Item = (f64, f64)> + Clone) -> f64 {
    let n = points.clone().count() as f64;
    let (sx, sy) = points
        .clone()
        .fold((0.0, 0.0), |(a, b), (x, y)| (a + x, b + y));
    let (mx, my) = (sx / n, sy / n);
    let (num, den) = points.fold((0.0, 0.0), |(a, b), (x, y)| {
        (a + (x - mx) * (y - my), b + (x - mx) * (x - mx))
    });
    num / den
}

/// Removes each run's least-squares line from column `col` of `rows` (position in
/// column 0), then shifts it to read 0 at the first position.
fn detrend(rows: &mut [Vec<f64>], col: usize) {
    let slope = lsq_slope(rows.iter().map(|r| (r[0], r[col])));
    let n = rows.len() as f64;
    let mx = rows.iter().map(|r| r[0]).sum::<f64>() / n;
    let my = rows.iter().map(|r| r[col]).sum::<f64>() / n;
    for r in rows.iter_mut() {
        r[col] -= my + slope * (r[0] - mx);
    }
    let first = rows[0][col];
    for r in rows.iter_mut() {
        r[col] -= first;
    }
}

/// The emulated machine.
#[derive(Debug, Clone)]
pub struct VolumetricMachine {
    pub structure: Structure,
    pub travel_mm: [f64; 3],
    pub tool_offset_mm: [f64; 3],
    pub work_offset_mm: [f64; 3],
    /// E_C0Y, E_B0Z, E_A0Z (rad).
    pub squareness_rad: [f64; 3],
    errors: [[ErrorFn; 6]; 3],
}

impl VolumetricMachine {
    /// A TC500-like machine (500 x 400 x 400 mm) with seeded errors.
    pub fn new(structure: Structure, seed: u64) -> VolumetricMachine {
        let travel_mm = [500.0, 400.0, 400.0];
        let mut rng = Rng::new(seed ^ 0x766f_6c75_6d65);
        let errors = std::array::from_fn(|a| {
            let l = travel_mm[a];
            std::array::from_fn(|c| {
                if c == a {
                    ErrorFn::random(&mut rng, l, 0.030, 0.006)
                } else if c < 3 {
                    ErrorFn::random(&mut rng, l, 0.004, 0.006)
                } else {
                    ErrorFn::random(&mut rng, l, 20e-6, 20e-6)
                }
            })
        });
        let squareness_rad = std::array::from_fn(|_| rng.range(-40e-6, 40e-6));
        let mut m = VolumetricMachine {
            structure,
            travel_mm,
            tool_offset_mm: [0.0, 0.0, 0.0],
            work_offset_mm: [0.0, 0.0, 0.0],
            squareness_rad,
            errors,
        };
        m.straightness_about_mean_lines();
        m
    }

    /// ISO 230-1's frame: each axis's straightness is its deviation from the
    /// least-squares line of its trajectory, and the lines' angles are the squareness
    /// constants (X the reference). So the straightness that a laser reads along each
    /// axis's line through the reference point, squareness aside, gets a zero
    /// least-squares slope: each straightness function's linear term is corrected (the
    /// readings are linear in it; two passes settle the second-order rest).
    fn straightness_about_mean_lines(&mut self) {
        for _ in 0..2 {
            let mut square_free = self.clone();
            square_free.squareness_rad = [0.0; 3];
            square_free.tool_offset_mm = [0.0; 3];
            square_free.work_offset_mm = [0.0; 3];
            for a in 0..3 {
                let l = self.travel_mm[a];
                // At the campaign's positions (every 25 mm), where the laser's software
                // fits its line.
                let n = (l / 25.0).round() as usize;
                let pts: Vec<(f64, [f64; 3])> = (0..=n)
                    .map(|i| {
                        let mut q = [0.0; 3];
                        q[a] = l * i as f64 / n as f64;
                        (q[a], square_free.true_error(q))
                    })
                    .collect();
                for c in (0..3).filter(|&c| c != a) {
                    let slope = lsq_slope(pts.iter().map(|p| (p.0, p.1[c])));
                    // The reading holds +δ for a tool-side axis, −δ for a workpiece one.
                    let sign = if self.structure.moves_work(a) {
                        -1.0
                    } else {
                        1.0
                    };
                    self.errors[a][c].lin -= sign * slope * l;
                }
            }
        }
    }

    /// The true error motion `component` (0..3 translations mm, 3..6 rotations rad) of
    /// `axis` at position `q`.
    pub fn error_motion(&self, axis: usize, component: usize, q: f64) -> f64 {
        self.errors[axis][component].at(q)
    }

    fn carriage(&self, axis: usize, q: f64, moves_work: bool) -> Htm {
        let [c0y, b0z, a0z] = self.squareness_rad;
        let dir = match axis {
            0 => [1.0, 0.0, 0.0],
            1 => [-c0y.sin(), c0y.cos(), 0.0],
            _ => [b0z.sin(), -a0z.sin() * b0z.cos(), a0z.cos() * b0z.cos()],
        };
        let s = if moves_work { -q } else { q };
        let e: [f64; 6] = std::array::from_fn(|c| self.error_motion(axis, c, q));
        translation(s * dir[0], s * dir[1], s * dir[2])
            * exact_error(e[0], e[1], e[2], e[3], e[4], e[5])
    }

    /// The tool frame in the workpiece frame, exactly, for command `q` (mm).
    pub fn relative(&self, q: [f64; 3]) -> Htm {
        let t = self.tool_offset_mm;
        let w = self.work_offset_mm;
        let tool = self
            .structure
            .tool_chain()
            .iter()
            .rev()
            .fold(translation(t[0], t[1], t[2]), |acc, &a| {
                self.carriage(a, q[a], false) * acc
            });
        let work = self
            .structure
            .work_chain()
            .iter()
            .rev()
            .fold(translation(w[0], w[1], w[2]), |acc, &a| {
                self.carriage(a, q[a], true) * acc
            });
        work.try_inverse().expect("rigid transforms invert") * tool
    }

    /// Where the tool point really is relative to the workpiece reference point (mm).
    pub fn tool_in_work(&self, q: [f64; 3]) -> [f64; 3] {
        let p = self.relative(q) * Vector4::new(0.0, 0.0, 0.0, 1.0);
        [p.x, p.y, p.z]
    }

    /// The true volumetric error at command `q` (mm): real minus nominal tool point.
    pub fn true_error(&self, q: [f64; 3]) -> [f64; 3] {
        let p = self.tool_in_work(q);
        std::array::from_fn(|k| p[k] - (q[k] + self.tool_offset_mm[k] - self.work_offset_mm[k]))
    }

    /// The simulated campaign: (file name, contents) of every instrument file.
    pub fn campaign(&self, seed: u64) -> Vec<(String, String)> {
        let mut rng = Rng::new(seed ^ 0x6361_6d70);
        let mut probe = self.clone();
        probe.tool_offset_mm = [0.0; 3];
        probe.work_offset_mm = [0.0; 3];
        let names = ['X', 'Y', 'Z'];
        let comp = ['X', 'Y', 'Z', 'A', 'B', 'C'];
        let mut files = Vec::new();
        for a in 0..3 {
            let angular: Vec<usize> = (3..6).filter(|&c| c != 3 + a).collect();
            let roll = 3 + a;
            let axis = names[a];
            let mut laser = format!(
                "# instrument: laser interferometer\n# axis: {axis}\n# straightness: least-squares line removed, zero at position 0\n# uncertainty_um: 1.0\n# uncertainty_urad: 1.0\nrun,position_mm"
            );
            for c in 0..3 {
                laser += &format!(",E_{}{axis}_um", comp[c]);
            }
            for &c in &angular {
                laser += &format!(",E_{}{axis}_urad", comp[c]);
            }
            laser.push('\n');
            let mut level = format!(
                "# instrument: {}\n# axis: {axis}\n# uncertainty_urad: 1.0\nrun,position_mm,E_{}{axis}_urad\n",
                if a == 2 { "angular interferometer optics" } else { "electronic level" },
                comp[roll]
            );
            let n = (self.travel_mm[a] / 25.0).round() as usize;
            for run in 1..=3 {
                let mut rows: Vec<Vec<f64>> = Vec::with_capacity(n + 1);
                for i in 0..=n {
                    let pos = self.travel_mm[a] * i as f64 / n as f64;
                    let mut q = [0.0; 3];
                    q[a] = pos;
                    let rel = probe.relative(q);
                    let d = probe.true_error(q);
                    // Rotation part of a rigid transform as Rz·Ry·Rx (tool vs workpiece).
                    let ang = [
                        rel[(2, 1)].atan2(rel[(2, 2)]),
                        -rel[(2, 0)].asin(),
                        rel[(1, 0)].atan2(rel[(0, 0)]),
                    ];
                    let mut row = vec![pos];
                    row.extend(d.iter().map(|v| v * 1e3 + 0.3 * rng.normal()));
                    row.extend(
                        angular
                            .iter()
                            .map(|&c| ang[c - 3] * 1e6 + 0.3 * rng.normal()),
                    );
                    rows.push(row);
                    level += &format!(
                        "{run},{pos},{:.4}\n",
                        ang[roll - 3] * 1e6 + 0.3 * rng.normal()
                    );
                }
                // The straightness optics are aligned to the line of motion: the
                // software removes the least-squares line.
                for c in (0..3).filter(|&c| c != a) {
                    detrend(&mut rows, 1 + c);
                }
                for row in rows {
                    laser += &format!("{run},{}", row[0]);
                    for v in &row[1..] {
                        laser += &format!(",{v:.4}");
                    }
                    laser.push('\n');
                }
            }
            files.push((format!("laser_{axis}.csv"), laser));
            files.push((format!("level_{axis}.csv"), level));
        }
        for circle in BallbarCircle::standard() {
            files.push((
                format!("ballbar_{}.csv", BALLBAR_PLANES[circle.plane].0),
                probe.ballbar(&circle, seed),
            ));
        }
        files
    }
}

/// Where the dot board lies for one height of the camera plan: its surface at
/// `origin_mm[2]` in the workpiece frame (on a riser of that height), its origin at
/// `origin_mm[0..2]` and its x axis turned by `rotation_rad` about Z. The board is put on
/// each riser against a fence: placements differ by tenths of a mm and up to 0.2 mrad.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoardPlacement {
    pub origin_mm: [f64; 3],
    pub rotation_rad: f64,
}

/// The camera measurement plan: the board's dots seen at every `xs` x `ys` point with
/// the board raised to each height in `zs` (the first height is the reference), in
/// `runs` repeated runs.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraPlan {
    pub xs: Vec<f64>,
    pub ys: Vec<f64>,
    pub zs: Vec<f64>,
    pub runs: usize,
}

impl CameraPlan {
    /// Every 25 mm over X and Y (the laser's spacing), heights 0, 150 and 300 mm, 2 runs.
    pub fn default_for(travel_mm: [f64; 3]) -> CameraPlan {
        let grid = |l: f64| {
            let n = (l / 25.0).round() as usize;
            (0..=n)
                .map(|i| l * i as f64 / n as f64)
                .collect::<Vec<f64>>()
        };
        CameraPlan {
            xs: grid(travel_mm[0]),
            ys: grid(travel_mm[1]),
            zs: vec![0.0, 150.0, 300.0],
            runs: 2,
        }
    }
}

impl VolumetricMachine {
    /// What the camera at the spindle sees at command `q` of a board placed at
    /// `placement`: the board point on its optical axis (the tool frame's z axis through
    /// the tool point, which is the camera's focal point) and the image's extra rotation,
    /// as a [`CameraPose`] for [`render`].
    pub fn camera_pose(&self, q: [f64; 3], placement: &BoardPlacement) -> CameraPose {
        let rel = self.relative(q);
        let p = [rel[(0, 3)], rel[(1, 3)], rel[(2, 3)]];
        let d = [rel[(0, 2)], rel[(1, 2)], rel[(2, 2)]];
        let o = placement.origin_mm;
        let lambda = (o[2] - p[2]) / d[2];
        let hit = [p[0] + lambda * d[0] - o[0], p[1] + lambda * d[1] - o[1]];
        let (s, c) = placement.rotation_rad.sin_cos();
        CameraPose {
            centre_mm: [c * hit[0] + s * hit[1], -s * hit[0] + c * hit[1]],
            rotation_rad: rel[(1, 0)].atan2(rel[(0, 0)]) - placement.rotation_rad,
        }
    }

    /// The frame the camera grabs at command `q` (world's renderer at the pose above).
    pub fn camera_frame(
        &self,
        q: [f64; 3],
        placement: &BoardPlacement,
        board: &Board,
        camera: &CameraModel,
        noise_seed: u64,
    ) -> RenderedFrame {
        render(board, camera, &self.camera_pose(q, placement), noise_seed)
    }

    /// The board's placement on each of the plan's risers (truth, seeded).
    pub fn board_placements(&self, plan: &CameraPlan, seed: u64) -> Vec<BoardPlacement> {
        let mut rng = Rng::new(seed ^ 0x0062_6f61_7264);
        plan.zs
            .iter()
            .map(|&z| BoardPlacement {
                // Riser heights are ground to a few µm of nominal.
                origin_mm: [
                    rng.range(-0.3, 0.3),
                    rng.range(-0.3, 0.3),
                    z + rng.range(-0.005, 0.005),
                ],
                rotation_rad: rng.range(-2e-4, 2e-4),
            })
            .collect()
    }

    /// The simulated camera campaign `camera.csv`: for each run, height and plan point
    /// (numbered `point`), the command and the board coordinates of the image centre as
    /// the localizer reports them (0.05 µm localization noise, stated uncertainty 0.2 µm).
    /// Returns the file and the placements used (truth).
    pub fn camera_campaign(&self, plan: &CameraPlan, seed: u64) -> (String, Vec<BoardPlacement>) {
        let placements = self.board_placements(plan, seed);
        let mut rng = Rng::new(seed ^ 0x6361_6d65_7261);
        let mut probe = self.clone();
        probe.tool_offset_mm = [0.0; 3];
        probe.work_offset_mm = [0.0; 3];
        let mut f = String::from(
            "# instrument: camera at the spindle, dot board on risers\n# uncertainty_um: 0.2\n\
             run,point,x_mm,y_mm,z_mm,board_x_mm,board_y_mm\n",
        );
        for run in 1..=plan.runs {
            let mut point = 0;
            for (k, &z) in plan.zs.iter().enumerate() {
                for &y in &plan.ys {
                    for &x in &plan.xs {
                        let pose = probe.camera_pose([x, y, z], &placements[k]);
                        let b = pose.centre_mm;
                        f += &format!(
                            "{run},{point},{x},{y},{z},{:.6},{:.6}\n",
                            b[0] + 5e-5 * rng.normal(),
                            b[1] + 5e-5 * rng.normal()
                        );
                        point += 1;
                    }
                }
            }
        }
        (f, placements)
    }
}

/// A ball-bar test's circle: in `plane` (0 XY, 1 XZ, 2 YZ; the angle runs from the
/// plane's first axis towards its second), about the pivot at command `centre_mm`, of
/// the bar's nominal length `radius_mm`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BallbarCircle {
    pub plane: usize,
    pub centre_mm: [f64; 3],
    pub radius_mm: f64,
}

/// The plane names and their axes.
pub const BALLBAR_PLANES: [(&str, usize, usize); 3] = [("XY", 0, 1), ("XZ", 0, 2), ("YZ", 1, 2)];

impl BallbarCircle {
    /// The three circles of the simulated campaign: R 150 mm about the middle of the
    /// 500 x 400 x 400 mm volume.
    pub fn standard() -> [BallbarCircle; 3] {
        std::array::from_fn(|plane| BallbarCircle {
            plane,
            centre_mm: [250.0, 200.0, 200.0],
            radius_mm: 150.0,
        })
    }

    /// The command at angle `deg` on the circle.
    pub fn command(&self, deg: f64) -> [f64; 3] {
        let (_, i, j) = BALLBAR_PLANES[self.plane];
        let (s, c) = deg.to_radians().sin_cos();
        let mut q = self.centre_mm;
        q[i] += self.radius_mm * c;
        q[j] += self.radius_mm * s;
        q
    }
}

impl VolumetricMachine {
    /// The ball-bar file of one circle, as ISO 230-4's test reads it: the bar's length
    /// deviation from nominal (µm) every degree, one run counter-clockwise and one
    /// clockwise (listed by angle). The pivot ball is set on the table where the tool
    /// ball sits at the centre command, within a few µm (the setting error, seeded);
    /// the tool ball is the tool point. Noise 0.1 µm, stated uncertainty 0.5 µm.
    pub fn ballbar(&self, circle: &BallbarCircle, seed: u64) -> String {
        let mut rng = Rng::new(seed ^ 0x6261_6c6c ^ circle.plane as u64);
        let centre = self.tool_in_work(circle.centre_mm);
        let pivot: [f64; 3] = std::array::from_fn(|k| centre[k] + rng.range(-0.003, 0.003));
        let c = circle.centre_mm;
        let mut f = format!(
            "# instrument: ball bar\n# plane: {}\n# radius_mm: {}\n# centre_mm: {} {} {}\n# uncertainty_um: 0.5\nrun,angle_deg,deviation_um\n",
            BALLBAR_PLANES[circle.plane].0,
            circle.radius_mm,
            c[0],
            c[1],
            c[2]
        );
        for run in 1..=2 {
            for k in 0..360 {
                let p = self.tool_in_work(circle.command(k as f64));
                let d = (0..3)
                    .map(|i| (p[i] - pivot[i]).powi(2))
                    .sum::<f64>()
                    .sqrt();
                f += &format!(
                    "{run},{k},{:.4}\n",
                    (d - circle.radius_mm) * 1e3 + 0.1 * rng.normal()
                );
            }
        }
        f
    }
}

/// The machine behind an N-axis controller emulator ([`crate::axes::AxesMachine`]):
/// X, Y, Z over the travel, 5000 mm/min; no probe target. The controller moves the
/// axes; where the tool point really is comes from [`VolumetricMachine::tool_in_work`].
pub struct VolumetricWorkpiece(pub VolumetricMachine);

impl crate::axes::Workpiece for VolumetricWorkpiece {
    fn axes(&self) -> usize {
        3
    }

    fn limits(&self, axis: usize) -> crate::axes::AxisLimits {
        crate::axes::AxisLimits {
            min: 0.0,
            max: self.0.travel_mm[axis.min(2)],
            max_rate: 5000.0,
        }
    }

    fn probe_contact(
        &mut self,
        _: &crate::axes::AxesPosition,
        _: &crate::axes::AxesPosition,
    ) -> Option<crate::axes::AxesPosition> {
        None
    }

    fn probe_touching(&self, _: &crate::axes::AxesPosition) -> bool {
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn errors_are_realistic_and_zero_at_the_origin() {
        let m = VolumetricMachine::new(Structure::Xyfz, 7);
        let mut big: f64 = 0.0;
        for a in 0..3 {
            for c in 0..6 {
                assert_eq!(m.error_motion(a, c, 0.0), 0.0);
                let max = (0..=100)
                    .map(|i| {
                        m.error_motion(a, c, m.travel_mm[a] * i as f64 / 100.0)
                            .abs()
                    })
                    .fold(0.0, f64::max);
                let limit = if c < 3 { 0.06 } else { 80e-6 };
                assert!(max < limit, "axis {a} component {c}: {max}");
                big = big.max(if c == a { max } else { 0.0 });
            }
        }
        assert!(big > 0.005, "positioning errors reach several µm: {big}");
        let e = m.true_error([500.0, 400.0, 400.0]);
        assert!(e.iter().any(|v| v.abs() > 0.005), "{e:?}");
    }

    #[test]
    fn a_pure_positioning_error_of_a_table_axis_moves_the_tool_back() {
        // XYFZ: X carries the workpiece. A carriage positioning error +d moves the
        // workpiece +d, so the tool lands at -d relative to it.
        let mut m = VolumetricMachine::new(Structure::Xyfz, 1);
        m.squareness_rad = [0.0; 3];
        for a in 0..3 {
            for c in 0..6 {
                m.errors[a][c].lin = 0.0;
                m.errors[a][c].waves = [(0.0, 1.0, 0.0); 3];
            }
        }
        m.errors[0][0].lin = 0.010;
        let e = m.true_error([250.0, 0.0, 0.0]);
        assert!((e[0] + 0.005).abs() < 1e-12 && e[1].abs() < 1e-12, "{e:?}");
    }

    fn perfect(structure: Structure) -> VolumetricMachine {
        let mut m = VolumetricMachine::new(structure, 1);
        m.squareness_rad = [0.0; 3];
        for a in 0..3 {
            for c in 0..6 {
                m.errors[a][c].lin = 0.0;
                m.errors[a][c].waves = [(0.0, 1.0, 0.0); 3];
            }
        }
        m
    }

    #[test]
    fn the_camera_sees_the_pitch_of_a_table_axis_grow_with_height() {
        // XYFZ, X carries the board: E_BX = 20 µrad at x = 250 (linear 40 µrad over
        // 500 mm). The tool point at height z lands -z·E_BX off in x (README's ex), so
        // raising the board from 0 to 300 mm moves the seen point by -6 µm.
        let mut m = perfect(Structure::Xyfz);
        m.errors[0][4].lin = 40e-6;
        let flat = |z: f64| BoardPlacement {
            origin_mm: [0.0, 0.0, z],
            rotation_rad: 0.0,
        };
        let low = m.camera_pose([250.0, 100.0, 0.0], &flat(0.0)).centre_mm;
        let high = m.camera_pose([250.0, 100.0, 300.0], &flat(300.0)).centre_mm;
        assert!((high[0] - low[0] + 0.006).abs() < 1e-9, "{low:?} {high:?}");
        assert!((high[1] - low[1]).abs() < 1e-9);
        // A board turned by 1 mrad at (1, 2) mm: the seen point in board coordinates.
        let p = BoardPlacement {
            origin_mm: [1.0, 2.0, 0.0],
            rotation_rad: 1e-3,
        };
        let c = perfect(Structure::Xyfz)
            .camera_pose([101.0, 2.0, 0.0], &p)
            .centre_mm;
        let want = [100.0 * 1e-3f64.cos(), -100.0 * 1e-3f64.sin()];
        assert!((c[0] - want[0]).abs() < 1e-12 && (c[1] - want[1]).abs() < 1e-12);
    }

    #[test]
    fn rendered_frame_centres_on_the_seen_board_point() {
        let m = VolumetricMachine::new(Structure::Xyfz, 5);
        let board = Board::nominal(
            "test",
            0.5,
            0.25,
            protocol::Polarity::DarkOnLight,
            1200,
            1000,
            [-50.0, -50.0],
        );
        let camera = CameraModel {
            model: "test".into(),
            width: 64,
            height: 48,
            bit_depth: 8,
            um_per_px: 20.0,
            rotation_deg: 0.0,
            mirrored: false,
            distortion_px_at_corner: 0.0,
            blur_sigma_px: 0.0,
            noise_sigma: 0.0,
            background_level: 0.9,
            dot_level: 0.1,
            illumination_gradient: 0.0,
            illumination_angle_deg: 0.0,
            vignetting: 0.0,
        };
        let place = BoardPlacement {
            origin_mm: [0.0, 0.0, 200.0],
            rotation_rad: 0.0,
        };
        let q = [250.0, 100.0, 200.0];
        let pose = m.camera_pose(q, &place);
        let frame = m.camera_frame(q, &place, &board, &camera, 1);
        assert!(!frame.dots.is_empty());
        for d in &frame.dots {
            let b = board.true_xy(d.i, d.j).unwrap();
            let back = camera.pixel_to_board(&pose, d.centre_px);
            assert!((back[0] - b[0]).abs() < 1e-9 && (back[1] - b[1]).abs() < 1e-9);
        }
    }

    #[test]
    fn camera_campaign_lists_every_point_of_the_plan() {
        let m = VolumetricMachine::new(Structure::Xyfz, 3);
        let plan = CameraPlan::default_for(m.travel_mm);
        let (f, placements) = m.camera_campaign(&plan, 9);
        assert_eq!(placements.len(), 3);
        // 21 x 17 points at 3 heights, 2 runs.
        assert_eq!(f.lines().filter(|l| l.starts_with("2,")).count(), 1071);
        assert!(f.contains("\nrun,point,x_mm,y_mm,z_mm,board_x_mm,board_y_mm\n1,0,0,0,0,"));
    }

    #[test]
    fn campaign_files_have_the_documented_columns() {
        let files = VolumetricMachine::new(Structure::Xyfz, 3).campaign(4);
        let names: Vec<&str> = files.iter().map(|f| f.0.as_str()).collect();
        assert_eq!(
            names,
            [
                "laser_X.csv",
                "level_X.csv",
                "laser_Y.csv",
                "level_Y.csv",
                "laser_Z.csv",
                "level_Z.csv",
                "ballbar_XY.csv",
                "ballbar_XZ.csv",
                "ballbar_YZ.csv"
            ]
        );
        assert!(files[4]
            .1
            .contains("run,position_mm,E_XZ_um,E_YZ_um,E_ZZ_um,E_AZ_urad,E_BZ_urad\n"));
        assert!(files[1].1.contains("run,position_mm,E_AX_urad\n"));
        // 3 runs of 21 positions on X.
        assert_eq!(
            files[0].1.lines().filter(|l| l.starts_with("3,")).count(),
            21
        );
    }
}
