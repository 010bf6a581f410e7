//! Frame renderer: the image the simulated camera sees of a calibration dot board at the
//! camera's TRUE pose.
//!
//! The pipeline follows the light, one physical effect per step, so each can be switched
//! off in a camera file and its effect on the localizer studied on its own:
//! 1. reflectance: the plate level everywhere, the dot level inside each dot, with
//!    exact-area anti-aliasing at the dot edges (a pixel gets the exact area fraction of
//!    its square that the dot covers), so a dot's intensity centroid is its true centre
//!    to a few thousandths of a pixel (the residual is inherent to sampling a disc on a
//!    pixel grid, not an approximation of the area: < 3e-3 px for radii 5..40 px, less
//!    for larger dots) and any larger centroid bias the localizer shows is its own;
//! 2. illumination: a linear gradient and a quadratic vignetting, multiplicative;
//! 3. optical blur: a separable, normalised Gaussian;
//! 4. sensor: additive Gaussian noise in grey levels, then rounding and clipping to the
//!    bit depth.
//!
//! Geometry comes only from [`CameraModel::board_to_pixel`] /
//! [`CameraModel::pixel_to_board`]; this module never re-derives the mapping, so the
//! listed dot centres are exactly what the camera model says.
//!
//! Speed: the frame is one `f32` buffer, dots touch only their bounding boxes, the
//! horizontal blur runs in place row by row and the vertical blur is fused with noise and
//! quantisation, so the whole frame is swept twice.

use crate::camera::{CameraModel, CameraPose};
use crate::rng::Rng;
use protocol::{Board, MonoImage, Pixels, Polarity};

/// A board dot whose centre lies inside the rendered frame.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderedDot {
    /// Board index along board +x.
    pub i: i64,
    /// Board index along board +y.
    pub j: i64,
    /// Exact image position of the dot centre (distorted pixels, integer = pixel centre).
    pub centre_px: [f64; 2],
}

/// A rendered camera frame plus the ground truth of what is in it.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderedFrame {
    pub image: MonoImage,
    /// Every board dot whose centre lies inside the frame, i.e. inside the pixel area
    /// `[-0.5, W-0.5) x [-0.5, H-0.5)`, in row-major board order (j, then i). Dots cut by
    /// the frame edge are still drawn (their visible part) but listed only when their
    /// centre is inside.
    pub dots: Vec<RenderedDot>,
}

/// Below this blur sigma (pixels) the Gaussian is narrower than the pixel and is skipped.
const MIN_BLUR_SIGMA_PX: f64 = 0.05;

/// Kernel half-width in sigmas: the discarded tails hold < 5e-4 of the weight.
const BLUR_RADIUS_SIGMAS: f64 = 3.5;

/// Largest certified deviation of a dot from nominal, as a fraction of pitch (the board
/// loader rejects more); it widens the board index window so no dot is missed.
const CERT_MARGIN_OF_PITCH: f64 = 0.1;

/// Render the frame `cam` sees of `board` at `pose`, with sensor noise drawn from
/// `Rng::new(noise_seed)` (same inputs and seed give the same frame, bit for bit).
///
/// Output is `Pixels::Mono16` for `bit_depth == 16` and `Pixels::Mono8` otherwise (the
/// camera loader only admits 8 and 16).
pub fn render(
    board: &Board,
    cam: &CameraModel,
    pose: &CameraPose,
    noise_seed: u64,
) -> RenderedFrame {
    render_damaged(board, cam, pose, noise_seed, &Damage::default())
}

/// Damage on a board: dots that are missing, and extra blobs of dot material (dirt, or a
/// bridge that merges two dots), drawn like dots.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Damage {
    /// Board indices (i, j) of dots not drawn.
    pub missing: std::collections::HashSet<(i64, i64)>,
    /// Extra discs: centre on the board (mm) and diameter (mm).
    pub blobs: Vec<([f64; 2], f64)>,
}

/// [`render`] of a damaged board (see [`crate::plate::damage`]).
pub fn render_damaged(
    board: &Board,
    cam: &CameraModel,
    pose: &CameraPose,
    noise_seed: u64,
    damage: &Damage,
) -> RenderedFrame {
    let (w, h) = (cam.width as usize, cam.height as usize);
    let (background, dot) = levels(board, cam);
    let mut buf = vec![background as f32; w * h];
    let amplitude = (dot - background) as f32;
    let mut dots = draw_dots(board, cam, pose, &mut buf, amplitude, &damage.missing);
    let mm_per_px = cam.um_per_px / 1000.0;
    let reach = 0.5 * (cam.width as f64).hypot(cam.height as f64) * mm_per_px + 1.0;
    for (xy, d) in &damage.blobs {
        if (xy[0] - pose.centre_mm[0]).hypot(xy[1] - pose.centre_mm[1]) > reach {
            continue;
        }
        let c = cam.board_to_pixel(pose, *xy);
        let r = 0.5 * d / mm_per_px;
        if r > 0.0 && r.is_finite() {
            // Dot material: coverage adds up to at most the full dot level.
            rasterise_disc(c, r, w, h, |x, y, cov| {
                let v = &mut buf[y * w + x];
                let full = background as f32 + amplitude;
                let add = amplitude * cov as f32;
                *v = if amplitude < 0.0 {
                    (*v + add).max(full)
                } else {
                    (*v + add).min(full)
                };
            });
        }
    }
    dots.retain(|d| !damage.missing.contains(&(d.i, d.j)));
    illuminate_and_blur_rows(cam, &mut buf);
    let image = blur_columns_and_quantise(cam, &buf, noise_seed);
    RenderedFrame { image, dots }
}

/// (background, dot) reflectance as fractions of full scale. The camera file gives the two
/// levels, the board decides which one is brighter: a bright-on-dark board seen by a camera
/// configured for dark dots (or the reverse) swaps them, so a frame always matches the
/// board it claims to show.
fn levels(board: &Board, cam: &CameraModel) -> (f64, f64) {
    let (background, dot) = (cam.background_level, cam.dot_level);
    let dots_brighter = board.polarity == Polarity::BrightOnDark;
    if (dot > background) == dots_brighter || dot == background {
        (background, dot)
    } else {
        (dot, background)
    }
}

/// Add `amplitude * coverage` of every dot that can touch the frame to `buf`, and list the
/// dots whose centre is inside the frame.
fn draw_dots(
    board: &Board,
    cam: &CameraModel,
    pose: &CameraPose,
    buf: &mut [f32],
    amplitude: f32,
    missing: &std::collections::HashSet<(i64, i64)>,
) -> Vec<RenderedDot> {
    let (w, h) = (cam.width as usize, cam.height as usize);
    let mut dots = Vec::new();
    let Some((i_range, j_range)) = visible_index_range(board, cam, pose) else {
        return dots;
    };
    let mm_per_px = cam.um_per_px / 1000.0;
    let k = cam.distortion_k();
    let mm_to_radius_px = 0.5 / mm_per_px;
    let (wf, hf) = (w as f64, h as f64);
    for j in j_range {
        for i in i_range.clone() {
            let Some(xy) = board.true_xy(i, j) else {
                continue;
            };
            if !missing.is_empty() && missing.contains(&(i, j)) {
                continue;
            }
            let centre = cam.board_to_pixel(pose, xy);
            // Undistorted radius from the image centre: the board->image map before
            // distortion is a rotation and a scale, so it is the board distance / scale.
            let (dx, dy) = (xy[0] - pose.centre_mm[0], xy[1] - pose.centre_mm[1]);
            let ru2 = (dx * dx + dy * dy) / (mm_per_px * mm_per_px);
            // r -> r(1 + k r^2) stretches radially by 1 + 3k r^2 and tangentially by
            // 1 + k r^2; a small dot becomes a slight ellipse, modelled as the circle of the
            // mean magnification so its centre stays exact by symmetry.
            // A coded board's dots come in two sizes (protocol::board_code).
            let radius = board.dot_diameter_at(i, j) * mm_to_radius_px * (1.0 + 2.0 * k * ru2);
            if (-0.5..wf - 0.5).contains(&centre[0]) && (-0.5..hf - 0.5).contains(&centre[1]) {
                dots.push(RenderedDot {
                    i,
                    j,
                    centre_px: centre,
                });
            }
            if radius > 0.0 && radius.is_finite() {
                rasterise_disc(centre, radius, w, h, |x, y, cov| {
                    buf[y * w + x] += amplitude * cov as f32;
                });
            }
        }
    }
    dots
}

/// The board index window (i range, j range) whose dots can touch the frame, or None when
/// no board dot can. Computed from the board-coordinate bounding box of the frame border
/// (sampled along the edges, not only at the corners: with distortion the border's
/// pre-image bulges between the corners), widened by a dot radius, the certificate
/// tolerance and a couple of pixels. Never scans the whole board.
fn visible_index_range(
    board: &Board,
    cam: &CameraModel,
    pose: &CameraPose,
) -> Option<(std::ops::RangeInclusive<i64>, std::ops::RangeInclusive<i64>)> {
    const SAMPLES_PER_EDGE: usize = 16;
    let (x0, y0) = (-0.5, -0.5);
    let (x1, y1) = (cam.width as f64 - 0.5, cam.height as f64 - 0.5);
    let mut lo = [f64::INFINITY; 2];
    let mut hi = [f64::NEG_INFINITY; 2];
    let mut max_r2: f64 = 0.0;
    for n in 0..SAMPLES_PER_EDGE {
        let f = n as f64 / SAMPLES_PER_EDGE as f64;
        let (fx, fy) = (x0 + f * (x1 - x0), y0 + f * (y1 - y0));
        for p in [
            [fx, y0],
            [x1, fy],
            [x1 - (fx - x0), y1],
            [x0, y1 - (fy - y0)],
        ] {
            let b = cam.pixel_to_board(pose, p);
            for a in 0..2 {
                lo[a] = lo[a].min(b[a]);
                hi[a] = hi[a].max(b[a]);
            }
            let (dx, dy) = (b[0] - pose.centre_mm[0], b[1] - pose.centre_mm[1]);
            max_r2 = max_r2.max(dx * dx + dy * dy);
        }
    }
    if !(lo.iter().chain(&hi).all(|v| v.is_finite())) {
        return None;
    }
    let mm_per_px = cam.um_per_px / 1000.0;
    // Largest dot magnification anywhere in the frame (see `draw_dots`).
    let mag = (1.0 + 2.0 * cam.distortion_k() * max_r2 / (mm_per_px * mm_per_px)).max(1.0);
    let margin = board.max_dot_diameter_mm() / 2.0 * mag
        + CERT_MARGIN_OF_PITCH * board.pitch_mm
        + 2.0 * mm_per_px;
    let range = |a: usize, n: u32| {
        let to_index = |v: f64| (v - board.origin_mm[a]) / board.pitch_mm;
        // Clamp in f64 before converting: a pose far off the board gives huge indices.
        let first = to_index(lo[a] - margin).floor().clamp(-1.0, n as f64) as i64;
        let last = to_index(hi[a] + margin).ceil().clamp(-1.0, n as f64) as i64;
        let (first, last) = (first.max(0), last.min(n as i64 - 1));
        (first <= last).then_some(first..=last)
    };
    Some((range(0, board.cols)?, range(1, board.rows)?))
}

/// Call `emit(x, y, coverage)` for every frame pixel the disc (centre `c`, radius `r`, in
/// pixels) touches, with the exact area of disc ∩ pixel square (pixel (x, y) covers
/// `[x-0.5, x+0.5] x [y-0.5, y+0.5]`). Pixels wholly inside get exactly 1 without any
/// arithmetic; only pixels cut by the edge pay for the analytic integral.
fn rasterise_disc(
    c: [f64; 2],
    r: f64,
    w: usize,
    h: usize,
    mut emit: impl FnMut(usize, usize, f64),
) {
    if w == 0 || h == 0 {
        return;
    }
    // Bounding box, clamped in f64 first so far-away dots never overflow the casts.
    let clamp_to = |v: f64, n: usize| v.clamp(0.0, n as f64 - 1.0) as usize;
    let (xa, xb) = ((c[0] - r - 0.5).floor(), (c[0] + r + 0.5).ceil());
    let (ya, yb) = ((c[1] - r - 0.5).floor(), (c[1] + r + 0.5).ceil());
    if xb < 0.0 || yb < 0.0 || xa > w as f64 - 1.0 || ya > h as f64 - 1.0 {
        return;
    }
    let (x_lo, x_hi) = (clamp_to(xa, w), clamp_to(xb, w));
    let (y_lo, y_hi) = (clamp_to(ya, h), clamp_to(yb, h));
    let disc = Disc::new(r);
    for y in y_lo..=y_hi {
        // Square edges relative to the disc centre.
        let (v0, v1) = (y as f64 - 0.5 - c[1], y as f64 + 0.5 - c[1]);
        let near = if v0 <= 0.0 && v1 >= 0.0 {
            0.0
        } else {
            v0.abs().min(v1.abs())
        };
        if near >= r {
            continue;
        }
        let far = v0.abs().max(v1.abs());
        // The disc ∩ this row's band spans |u| < outer; a square with all of
        // |u| <= inner is wholly inside the disc (its farthest corners are inside).
        let outer = (r * r - near * near).sqrt();
        let inner = if far < r {
            (r * r - far * far).sqrt()
        } else {
            -1.0
        };
        let (cut0, cut1) = (disc.cut(v0), disc.cut(v1));
        for x in x_lo..=x_hi {
            let (u0, u1) = (x as f64 - 0.5 - c[0], x as f64 + 0.5 - c[0]);
            if u1 <= -outer || u0 >= outer {
                continue;
            }
            let cov = if u0 >= -inner && u1 <= inner {
                1.0
            } else {
                disc.coverage(u0, u1, &cut0, &cut1)
            };
            emit(x, y, cov);
        }
    }
}

/// A disc of radius `r` centred at the origin, with the exact area integrals the
/// rasteriser needs.
///
/// The area of the disc inside `[u0,u1] x [v0,v1]` is `A(v1) - A(v0)`, where
/// `A(v) = ∫_{u0}^{u1} below(v, t) dt` and `below(v, t)` is the length of the disc chord
/// at abscissa t lying under ordinate v. With `h(t) = sqrt(r^2 - t^2)` and
/// `s = sqrt(r^2 - v^2)`: on `|t| < s` the chord crosses v and `below = v + h`; on
/// `s < |t| < r` it lies wholly under v (`below = 2h`) if v > 0 and wholly over it
/// (`below = 0`) otherwise. Each piece integrates in closed form with the primitive
/// `P(t) = (t h(t) + r^2 asin(t / r)) / 2` of h.
struct Disc {
    r: f64,
    r2: f64,
}

/// An ordinate v cutting the disc: v, the half-chord s there and P(s) (P is odd, so
/// P(-s) = -P(s)). Computed once per pixel row edge and shared by the row's pixels.
struct Cut {
    v: f64,
    s: f64,
    ps: f64,
}

impl Disc {
    fn new(r: f64) -> Self {
        Disc { r, r2: r * r }
    }

    /// P(t), the primitive of sqrt(r^2 - t^2), for |t| <= r.
    #[inline]
    fn prim(&self, t: f64) -> f64 {
        let h = (self.r2 - t * t).max(0.0).sqrt();
        0.5 * (t * h + self.r2 * (t / self.r).clamp(-1.0, 1.0).asin())
    }

    fn cut(&self, v: f64) -> Cut {
        let s = (self.r2 - v * v).max(0.0).sqrt();
        Cut {
            v,
            s,
            ps: self.prim(s),
        }
    }

    /// Exact area of the disc inside `[u0,u1] x [cut0.v, cut1.v]` (u0 < u1, v0 < v1).
    fn coverage(&self, u0: f64, u1: f64, cut0: &Cut, cut1: &Cut) -> f64 {
        let a = u0.max(-self.r);
        let b = u1.min(self.r);
        if a >= b {
            return 0.0;
        }
        let (pa, pb) = (self.prim(a), self.prim(b));
        let area = Self::area_below(cut1, a, pa, b, pb) - Self::area_below(cut0, a, pa, b, pb);
        area.clamp(0.0, 1.0)
    }

    /// `A(v)` over `[a, b]` (already clipped to [-r, r]) with P(a), P(b) given.
    #[inline]
    fn area_below(cut: &Cut, a: f64, pa: f64, b: f64, pb: f64) -> f64 {
        let (v, s, ps) = (cut.v, cut.s, cut.ps);
        let mut area = 0.0;
        // |t| < s: below = v + h.
        let (lo, plo) = if a > -s { (a, pa) } else { (-s, -ps) };
        let (hi, phi) = if b < s { (b, pb) } else { (s, ps) };
        if lo < hi {
            area += phi - plo + v * (hi - lo);
        }
        if v > 0.0 {
            // s < |t| < r: the whole chord (2h) is under v.
            if a < -s {
                let phi = if b < -s { pb } else { -ps };
                area += 2.0 * (phi - pa);
            }
            if b > s {
                let plo = if a > s { pa } else { ps };
                area += 2.0 * (pb - plo);
            }
        }
        area
    }
}

/// Normalised Gaussian kernel of half-width ceil(3.5 sigma), or None when the blur is
/// negligible.
fn gaussian_kernel(sigma: f64) -> Option<Vec<f32>> {
    if !sigma.is_finite() || sigma < MIN_BLUR_SIGMA_PX {
        return None;
    }
    let radius = (BLUR_RADIUS_SIGMAS * sigma).ceil() as i64;
    let weights: Vec<f64> = (-radius..=radius)
        .map(|k| (-((k * k) as f64) / (2.0 * sigma * sigma)).exp())
        .collect();
    let sum: f64 = weights.iter().sum();
    Some(weights.iter().map(|v| (v / sum) as f32).collect())
}

/// The multiplicative illumination `I(p) = 1 + g ((p-c).u) / R_edge - v (|p-c| / R_corner)^2`
/// as a row part plus a column part (it is separable into a sum), so the per-pixel cost
/// is one add.
///
/// c is the image centre ((W-1)/2, (H-1)/2) and u = (cos a, sin a) in image axes.
/// R_edge is the distance from c along u to the frame edge (through pixel centres:
/// half-extents (W-1)/2, (H-1)/2), so the illumination where that ray leaves the frame is
/// exactly 1 + g, which is how the camera file defines the gradient. R_corner is the
/// distance from c to the corner pixel centre, where the vignetting term is exactly v.
/// Negative illumination (only possible with absurd settings) is clipped to 0.
struct Illumination {
    rows: Vec<f32>,
    cols: Vec<f32>,
}

impl Illumination {
    fn new(cam: &CameraModel) -> Self {
        let c = cam.centre();
        let (ux, uy) = (
            cam.illumination_angle_deg.to_radians().cos(),
            cam.illumination_angle_deg.to_radians().sin(),
        );
        let edge = |half: f64, u: f64| {
            if u.abs() > 1e-12 {
                half / u.abs()
            } else {
                f64::INFINITY
            }
        };
        let r_edge = edge(c[0], ux).min(edge(c[1], uy));
        let r_edge = if r_edge.is_finite() && r_edge > 0.0 {
            r_edge
        } else {
            1.0
        };
        let r_corner2 = (c[0] * c[0] + c[1] * c[1]).max(1e-12);
        let g = cam.illumination_gradient / r_edge;
        let v = cam.vignetting / r_corner2;
        let term = |d: f64, u: f64| (g * d * u - v * d * d) as f32;
        Illumination {
            rows: (0..cam.height)
                .map(|y| 1.0 + term(y as f64 - c[1], uy))
                .collect(),
            cols: (0..cam.width).map(|x| term(x as f64 - c[0], ux)).collect(),
        }
    }
}

/// Pass 1, in place, row by row: multiply by the illumination and apply the horizontal
/// blur (clamp-to-edge via a padded copy of the row).
fn illuminate_and_blur_rows(cam: &CameraModel, buf: &mut [f32]) {
    let w = cam.width as usize;
    if w == 0 {
        return;
    }
    let light = Illumination::new(cam);
    let kernel = gaussian_kernel(cam.blur_sigma_px);
    let radius = kernel.as_ref().map_or(0, |k| k.len() / 2);
    let mut padded = vec![0.0f32; w + 2 * radius];
    for (row, &row_light) in buf.chunks_exact_mut(w).zip(&light.rows) {
        let Some(kernel) = &kernel else {
            for (p, &col_light) in row.iter_mut().zip(&light.cols) {
                *p *= (row_light + col_light).max(0.0);
            }
            continue;
        };
        for ((dst, &p), &col_light) in padded[radius..radius + w]
            .iter_mut()
            .zip(row.iter())
            .zip(&light.cols)
        {
            *dst = p * (row_light + col_light).max(0.0);
        }
        let (first, last) = (padded[radius], padded[radius + w - 1]);
        padded[..radius].fill(first);
        padded[radius + w..].fill(last);
        // Tap-major order: each inner loop is a contiguous multiply-add the compiler
        // vectorises.
        row.fill(0.0);
        for (k, &wk) in kernel.iter().enumerate() {
            for (o, &p) in row.iter_mut().zip(&padded[k..k + w]) {
                *o += wk * p;
            }
        }
    }
}

/// Pass 2, row by row: vertical blur (clamp-to-edge), scale to full scale, add sensor
/// noise (row-major standard-normal draws from `Rng::new(seed)` through [`Ziggurat`], one
/// per pixel, none when sigma is 0), round and clip.
fn blur_columns_and_quantise(cam: &CameraModel, buf: &[f32], seed: u64) -> MonoImage {
    let (w, h) = (cam.width as usize, cam.height as usize);
    let sixteen = cam.bit_depth == 16;
    let full_scale: f32 = if sixteen {
        u16::MAX as f32
    } else {
        u8::MAX as f32
    };
    let kernel = gaussian_kernel(cam.blur_sigma_px).unwrap_or_else(|| vec![1.0]);
    let radius = kernel.len() / 2;
    let noise = cam.noise_sigma;
    let mut rng = Rng::new(seed);
    let normal = Ziggurat::new();
    let mut acc = vec![0.0f32; w];
    let mut out8 = if sixteen {
        Vec::new()
    } else {
        Vec::with_capacity(w * h)
    };
    let mut out16 = if sixteen {
        Vec::with_capacity(w * h)
    } else {
        Vec::new()
    };
    for y in 0..h {
        acc.fill(0.0);
        for (k, &wk) in kernel.iter().enumerate() {
            let src = (y + k).saturating_sub(radius).min(h - 1);
            for (a, &p) in acc.iter_mut().zip(&buf[src * w..(src + 1) * w]) {
                *a += wk * p;
            }
        }
        for a in acc.iter_mut() {
            *a *= full_scale;
        }
        if noise > 0.0 {
            for a in acc.iter_mut() {
                *a += (noise * normal.sample(&mut rng)) as f32;
            }
        }
        // `as` from float saturates, the clamp just makes the intent explicit.
        if sixteen {
            out16.extend(acc.iter().map(|a| a.round().clamp(0.0, full_scale) as u16));
        } else {
            out8.extend(acc.iter().map(|a| a.round().clamp(0.0, full_scale) as u8));
        }
    }
    let pixels = if sixteen {
        Pixels::Mono16(out16)
    } else {
        Pixels::Mono8(out8)
    };
    MonoImage::new(cam.width, cam.height, pixels).expect("renderer fills every pixel")
}

/// Standard-normal sampler by the ziggurat method (Marsaglia & Tsang 2000, in the ZIGNOR
/// form of Doornik 2005), fed by the bits of an [`Rng`].
///
/// Why not `Rng::normal`: its Box-Muller transform costs a log, a square root and a
/// sine/cosine pair per two draws, about 20 ns per pixel, which was 70 % of a 1280x1024
/// frame. The ziggurat needs one `next_u64` and one table compare for ~99 % of draws and
/// is still an exact normal distribution (the rare wedge and tail draws are corrected by
/// rejection). The tables are built per frame: 128 logs, negligible.
struct Ziggurat {
    /// Layer right edges; `x[0]` is the pseudo-width V / f(R) of the base layer (which
    /// includes the tail), `x[1] = R`, `x[LAYERS] = 0`.
    x: [f64; ZIG_LAYERS + 1],
    /// `x[i+1] / x[i]`: below this |u| a draw in layer i is inside the next layer's box
    /// and accepted at once.
    ratio: [f64; ZIG_LAYERS],
}

const ZIG_LAYERS: usize = 128;
/// Start of the tail and area of each layer for 128 layers (Marsaglia & Tsang).
const ZIG_R: f64 = 3.442_619_855_899;
const ZIG_V: f64 = 9.912_563_035_262_17e-3;

impl Ziggurat {
    fn new() -> Self {
        let density = |x: f64| (-0.5 * x * x).exp();
        let mut x = [0.0; ZIG_LAYERS + 1];
        x[0] = ZIG_V / density(ZIG_R);
        x[1] = ZIG_R;
        for i in 1..ZIG_LAYERS - 1 {
            x[i + 1] = (-2.0 * (ZIG_V / x[i] + density(x[i])).ln()).sqrt();
        }
        let mut ratio = [0.0; ZIG_LAYERS];
        for i in 0..ZIG_LAYERS {
            ratio[i] = x[i + 1] / x[i];
        }
        Ziggurat { x, ratio }
    }

    #[inline]
    fn sample(&self, rng: &mut Rng) -> f64 {
        loop {
            // Disjoint bits of one draw: the low 7 pick the layer, the top 53 the abscissa.
            let bits = rng.next_u64();
            let i = (bits as usize) & (ZIG_LAYERS - 1);
            let u = 2.0 * ((bits >> 11) as f64 * (1.0 / (1u64 << 53) as f64)) - 1.0;
            if u.abs() < self.ratio[i] {
                return u * self.x[i];
            }
            if i == 0 {
                return Self::tail(rng, u < 0.0);
            }
            // Wedge between the layer's box and the density: accept under the curve.
            let x = u * self.x[i];
            let f0 = (-0.5 * (self.x[i] * self.x[i] - x * x)).exp();
            let f1 = (-0.5 * (self.x[i + 1] * self.x[i + 1] - x * x)).exp();
            if f1 + rng.uniform() * (f0 - f1) < 1.0 {
                return x;
            }
        }
    }

    /// A draw from the normal tail beyond R (Marsaglia 1964).
    #[cold]
    fn tail(rng: &mut Rng, negative: bool) -> f64 {
        loop {
            // 1 - uniform is in (0, 1]: no log of zero.
            let x = (1.0 - rng.uniform()).ln() / ZIG_R;
            let y = (1.0 - rng.uniform()).ln();
            if -2.0 * y >= x * x {
                return if negative { x - ZIG_R } else { ZIG_R - x };
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    /// A small undistorted camera: 10 um/px, plain levels, no blur, noise or light falloff.
    fn camera(width: u32, height: u32) -> CameraModel {
        CameraModel {
            model: "test".into(),
            width,
            height,
            bit_depth: 8,
            um_per_px: 10.0,
            rotation_deg: 0.0,
            mirrored: false,
            distortion_px_at_corner: 0.0,
            blur_sigma_px: 0.0,
            noise_sigma: 0.0,
            background_level: 0.8,
            dot_level: 0.15,
            illumination_gradient: 0.0,
            illumination_angle_deg: 0.0,
            vignetting: 0.0,
        }
    }

    /// 0.4 mm pitch (40 px), 0.2 mm dots (radius 10 px), 60 x 50 points from the origin.
    fn board() -> Board {
        Board::nominal("test", 0.4, 0.2, Polarity::DarkOnLight, 60, 50, [0.0, 0.0])
    }

    fn pixels(img: &MonoImage) -> Vec<f64> {
        match &img.pixels {
            Pixels::Mono8(p) => p.iter().map(|&v| v as f64).collect(),
            Pixels::Mono16(p) => p.iter().map(|&v| v as f64).collect(),
        }
    }

    /// Every dot of the (small) test board whose centre maps inside the frame, by brute force.
    fn brute_force_dots(board: &Board, cam: &CameraModel, pose: &CameraPose) -> Vec<RenderedDot> {
        let (w, h) = (cam.width as f64, cam.height as f64);
        let mut out = Vec::new();
        for j in 0..board.rows as i64 {
            for i in 0..board.cols as i64 {
                let c = cam.board_to_pixel(pose, board.true_xy(i, j).unwrap());
                if c[0] >= -0.5 && c[0] < w - 0.5 && c[1] >= -0.5 && c[1] < h - 0.5 {
                    out.push(RenderedDot { i, j, centre_px: c });
                }
            }
        }
        out
    }

    /// Coverage sum and first moments of one rasterised disc.
    fn disc_moments(c: [f64; 2], r: f64) -> (f64, [f64; 2]) {
        let (mut sum, mut mx, mut my) = (0.0, 0.0, 0.0);
        rasterise_disc(c, r, 256, 256, |x, y, cov| {
            assert!((0.0..=1.0).contains(&cov));
            sum += cov;
            mx += x as f64 * cov;
            my += y as f64 * cov;
        });
        (sum, [mx / sum, my / sum])
    }

    #[test]
    fn coverage_is_the_exact_area() {
        // Closed-form single cases.
        let one = |c: [f64; 2], r: f64, x: usize, y: usize| {
            let mut v = 0.0;
            rasterise_disc(c, r, 8, 8, |px, py, cov| {
                if (px, py) == (x, y) {
                    v = cov;
                }
            });
            v
        };
        assert!((one([3.0, 3.0], 0.5, 3, 3) - PI / 4.0).abs() < 1e-14);
        let (r, d) = (0.6f64, 0.5f64);
        let segment = r * r * (d / r).acos() - d * (r * r - d * d).sqrt();
        assert!((one([3.0, 3.0], r, 3, 3) - (PI * r * r - 4.0 * segment)).abs() < 1e-14);
        assert!((one([3.0, 3.0], r, 4, 3) - segment).abs() < 1e-14);
        // A unit disc centred on a pixel corner puts a quarter disc in each of 4 pixels.
        for (x, y) in [(3, 3), (4, 3), (3, 4), (4, 4)] {
            assert!((one([3.5, 3.5], 1.0, x, y) - PI / 4.0).abs() < 1e-14);
        }
        assert_eq!(one([3.5, 3.5], 1.0, 5, 3), 0.0);
        assert_eq!(one([3.5, 3.5], 0.5f64.sqrt(), 2, 2), 0.0);
        // The whole disc, for sub-pixel and large radii at random sub-pixel centres.
        let mut rng = Rng::new(11);
        let mut radii = vec![0.1, 0.3, 0.5, 0.71, 1.0, 1.5, 2.3];
        radii.extend((0..300).map(|_| rng.range(5.0, 40.0)));
        for r in radii {
            let c = [100.0 + rng.uniform(), 120.0 + rng.uniform()];
            let (sum, _) = disc_moments(c, r);
            let want = PI * r * r;
            assert!(
                ((sum - want) / want).abs() < 1e-9,
                "r {r} c {c:?}: {sum} vs {want}"
            );
        }
    }

    #[test]
    fn dot_centroid_is_its_centre() {
        let mut rng = Rng::new(5);
        let (mut worst, mut worst_small, mut worst_large): (f64, f64, f64) = (0.0, 0.0, 0.0);
        for _ in 0..1000 {
            let r = rng.range(5.0, 40.0);
            let c = [120.0 + rng.uniform(), 127.0 + rng.uniform()];
            let (_, m) = disc_moments(c, r);
            let err = (m[0] - c[0]).abs().max((m[1] - c[1]).abs());
            worst = worst.max(err);
            if r < 10.0 {
                worst_small = worst_small.max(err);
            } else if r > 30.0 {
                worst_large = worst_large.max(err);
            }
        }
        println!(
            "worst coverage-centroid error: r 5..40 {worst:.2e} px, r 5..10 {worst_small:.2e}, r 30..40 {worst_large:.2e}"
        );
        assert!(worst < 0.005, "{worst}");
    }

    /// Background-normalised centroid of the dot near `c`: a plane fitted to the border ring
    /// of a local window stands for the local (illuminated) background B, and the weight
    /// (B - v) / B is proportional to the dot's coverage whatever the illumination.
    fn local_centroid(img: &MonoImage, c: [f64; 2], half: i64) -> Option<[f64; 2]> {
        let (cx, cy) = (c[0].round() as i64, c[1].round() as i64);
        let (w, h) = (img.width as i64, img.height as i64);
        if cx - half < 0 || cy - half < 0 || cx + half >= w || cy + half >= h {
            return None;
        }
        let at = |x: i64, y: i64| img.get(x as u32, y as u32) as f64;
        // Least-squares plane a + b dx + c dy over the 2-pixel ring: normal equations.
        let mut n = [[0.0f64; 3]; 3];
        let mut rhs = [0.0f64; 3];
        for dy in -half..=half {
            for dx in -half..=half {
                if dx.abs().max(dy.abs()) < half - 1 {
                    continue;
                }
                let f = [1.0, dx as f64, dy as f64];
                for a in 0..3 {
                    for b in 0..3 {
                        n[a][b] += f[a] * f[b];
                    }
                    rhs[a] += f[a] * at(cx + dx, cy + dy);
                }
            }
        }
        // The ring is symmetric, so the normal matrix is diagonal.
        let plane = [rhs[0] / n[0][0], rhs[1] / n[1][1], rhs[2] / n[2][2]];
        let (mut s, mut sx, mut sy) = (0.0, 0.0, 0.0);
        for dy in -half..=half {
            for dx in -half..=half {
                let b = plane[0] + plane[1] * dx as f64 + plane[2] * dy as f64;
                let wgt = (b - at(cx + dx, cy + dy)) / b;
                s += wgt;
                sx += wgt * (cx + dx) as f64;
                sy += wgt * (cy + dy) as f64;
            }
        }
        Some([sx / s, sy / s])
    }

    fn worst_centroid_error(frame: &RenderedFrame, half: i64) -> (f64, usize) {
        let mut worst: f64 = 0.0;
        let mut n = 0;
        for d in &frame.dots {
            if let Some(m) = local_centroid(&frame.image, d.centre_px, half) {
                worst = worst
                    .max((m[0] - d.centre_px[0]).abs())
                    .max((m[1] - d.centre_px[1]).abs());
                n += 1;
            }
        }
        (worst, n)
    }

    #[test]
    fn sharp_frame_centroids_are_exact() {
        let mut cam = camera(320, 256);
        cam.bit_depth = 16;
        cam.rotation_deg = 3.7;
        let frame = render(
            &board(),
            &cam,
            &CameraPose {
                centre_mm: [5.013, 4.027],
                rotation_rad: 0.0,
            },
            1,
        );
        let (worst, n) = worst_centroid_error(&frame, 13);
        println!("sharp 16-bit frame: {n} dots, worst centroid error {worst:.2e} px");
        assert!(n >= 20, "{n}");
        assert!(worst < 0.005, "{worst}");
    }

    #[test]
    fn listed_dots_match_the_camera_model_and_survive_blur_and_light() {
        let b = board();
        let mut cam = camera(320, 256);
        cam.bit_depth = 16;
        cam.rotation_deg = 7.0;
        cam.blur_sigma_px = 1.5;
        cam.illumination_gradient = 0.1;
        cam.illumination_angle_deg = 30.0;
        cam.vignetting = 0.05;
        let pose = CameraPose {
            centre_mm: [6.1234, 5.4321],
            rotation_rad: 0.002,
        };
        let frame = render(&b, &cam, &pose, 3);
        assert_eq!(frame.dots, brute_force_dots(&b, &cam, &pose));
        assert!(frame.dots.len() >= 40, "{}", frame.dots.len());
        let half = (10.0 + BLUR_RADIUS_SIGMAS * 1.5 + 3.0f64).ceil() as i64;
        let (worst, n) = worst_centroid_error(&frame, half);
        println!(
            "blurred, illuminated 16-bit frame: {n} dots, worst centroid error {worst:.2e} px"
        );
        assert!(n >= 20, "{n}");
        assert!(worst < 0.02, "{worst}");

        // The same in 8 bits: quantisation costs a little.
        cam.bit_depth = 8;
        let (worst8, _) = worst_centroid_error(&render(&b, &cam, &pose, 3), half);
        println!("same frame in 8 bits: worst centroid error {worst8:.2e} px");
        assert!(worst8 < 0.05, "{worst8}");

        // Distortion, mirroring and rotation: the listing still follows board_to_pixel.
        cam.distortion_px_at_corner = 3.0;
        cam.mirrored = true;
        cam.rotation_deg = -20.0;
        let frame = render(&b, &cam, &pose, 3);
        assert_eq!(frame.dots, brute_force_dots(&b, &cam, &pose));
        let (worst_d, _) = worst_centroid_error(&frame, half);
        println!("distorted (3 px at corner) 8-bit frame: worst centroid error {worst_d:.2e} px");
    }

    #[test]
    fn same_seed_same_frame_and_noise_has_the_configured_sigma() {
        let b = board();
        let mut cam = camera(320, 256);
        cam.noise_sigma = 2.0;
        cam.blur_sigma_px = 1.0;
        let pose = CameraPose {
            centre_mm: [4.0, 4.0],
            rotation_rad: 0.0,
        };
        let a = render(&b, &cam, &pose, 42);
        assert_eq!(a, render(&b, &cam, &pose, 42));
        assert_ne!(a.image, render(&b, &cam, &pose, 43).image);
        // Off the board the frame is plain background, so its spread is the noise alone.
        let blank = render(
            &b,
            &cam,
            &CameraPose {
                centre_mm: [-50.0, 0.0],
                rotation_rad: 0.0,
            },
            42,
        );
        let v = pixels(&blank.image);
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        let sd = (v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / v.len() as f64).sqrt();
        assert!((mean - 0.8 * 255.0).abs() < 0.05, "{mean}");
        // Rounding adds 1/12 grey^2 of variance.
        assert!((sd - (4.0f64 + 1.0 / 12.0).sqrt()).abs() < 0.03, "{sd}");
    }

    /// The listed dot nearest the frame centre (its neighbourhood is inside the frame).
    fn central_dot(frame: &RenderedFrame) -> &RenderedDot {
        let c = frame.image.centre();
        let d2 =
            |d: &RenderedDot| (d.centre_px[0] - c[0]).powi(2) + (d.centre_px[1] - c[1]).powi(2);
        frame
            .dots
            .iter()
            .min_by(|a, b| d2(a).total_cmp(&d2(b)))
            .expect("a dot in view")
    }

    #[test]
    fn sixteen_bit_frames_use_the_full_range() {
        let mut cam = camera(320, 256);
        cam.bit_depth = 16;
        let pose = CameraPose {
            centre_mm: [4.0, 4.0],
            rotation_rad: 0.0,
        };
        let frame = render(&board(), &cam, &pose, 1);
        assert_eq!(frame.image.bit_depth(), 16);
        assert!(matches!(frame.image.pixels, Pixels::Mono16(_)));
        let d = central_dot(&frame);
        let at = |p: [f64; 2]| frame.image.get(p[0].round() as u32, p[1].round() as u32);
        assert_eq!(at(d.centre_px), (0.15f64 * 65535.0).round() as u32);
        // Half a pitch away from a dot centre is plate.
        let between = [d.centre_px[0] + 20.0, d.centre_px[1] + 20.0];
        assert_eq!(at(between), (0.8f64 * 65535.0).round() as u32);
    }

    #[test]
    fn a_pose_off_the_board_gives_a_blank_frame() {
        let mut cam = camera(320, 256);
        cam.blur_sigma_px = 1.2;
        for centre_mm in [[-10.0, -10.0], [1e7, 3.0], [12.0, -1e9]] {
            let frame = render(
                &board(),
                &cam,
                &CameraPose {
                    centre_mm,
                    rotation_rad: 0.3,
                },
                9,
            );
            assert!(frame.dots.is_empty());
            // Blur is normalised and clamps at the edges: a flat frame stays flat.
            assert!(pixels(&frame.image).iter().all(|&v| v == 204.0));
        }
    }

    #[test]
    fn partial_board_and_dots_cut_by_the_frame_edge() {
        let b = board();
        let cam = camera(320, 256);
        // Board origin at the frame centre: only one quadrant holds dots.
        let pose = CameraPose {
            centre_mm: [0.0, 0.0],
            rotation_rad: 0.0,
        };
        let frame = render(&b, &cam, &pose, 1);
        assert_eq!(frame.dots, brute_force_dots(&b, &cam, &pose));
        assert_eq!(frame.dots.len(), 4 * 4);
        // The quadrant left of / below the board origin is plain plate.
        assert!((0..100).all(|y| (0..140).all(|x| frame.image.get(x, y + 150) == 204)));
        // Dot (5, 5) at board (2.0, 2.0) placed at pixel (-3, 100): centre outside, so not
        // listed, but its visible part is drawn.
        let pose = CameraPose {
            centre_mm: [3.625, 1.725],
            rotation_rad: 0.0,
        };
        let frame = render(&b, &cam, &pose, 1);
        let c = cam.board_to_pixel(&pose, [2.0, 2.0]);
        assert!(
            (c[0] + 3.0).abs() < 1e-9 && (c[1] - 100.0).abs() < 1e-9,
            "{c:?}"
        );
        assert!(!frame.dots.iter().any(|d| (d.i, d.j) == (5, 5)));
        assert!(frame.dots.iter().any(|d| (d.i, d.j) == (6, 5)));
        assert_eq!(frame.image.get(0, 100), 38);
        assert_eq!(frame.image.get(6, 100), 38);
        assert_eq!(frame.image.get(0, 80), 204);
    }

    #[test]
    fn bright_on_dark_boards_swap_the_levels() {
        let mut b = board();
        b.polarity = Polarity::BrightOnDark;
        let cam = camera(320, 256);
        let frame = render(
            &b,
            &cam,
            &CameraPose {
                centre_mm: [4.0, 4.0],
                rotation_rad: 0.0,
            },
            1,
        );
        let d = central_dot(&frame);
        let (x, y) = (d.centre_px[0].round() as u32, d.centre_px[1].round() as u32);
        assert_eq!(frame.image.get(x, y), 204);
        assert_eq!(frame.image.get(x + 20, y + 20), 38);
    }

    #[test]
    fn illumination_is_as_the_camera_file_defines_it() {
        let mut cam = camera(321, 257);
        cam.bit_depth = 16;
        cam.illumination_gradient = 0.1;
        let off = CameraPose {
            centre_mm: [-50.0, 0.0],
            rotation_rad: 0.0,
        };
        let fs: f64 = 0.8 * 65535.0;
        let img = render(&board(), &cam, &off, 1).image;
        // Gradient along +x: +10 % at the right edge, -10 % at the left, 1 at the centre.
        assert_eq!(img.get(320, 0) as f64, (fs * 1.1).round());
        assert_eq!(img.get(0, 256) as f64, (fs * 0.9).round());
        assert_eq!(img.get(160, 9) as f64, fs.round());
        // Along 90 degrees (image +y): the ray leaves through the bottom edge.
        cam.illumination_angle_deg = 90.0;
        let img = render(&board(), &cam, &off, 1).image;
        assert_eq!(img.get(5, 256) as f64, (fs * 1.1).round());
        // Vignetting: exactly v at the corner pixel centre, none at the centre.
        cam.illumination_gradient = 0.0;
        cam.vignetting = 0.05;
        let img = render(&board(), &cam, &off, 1).image;
        assert_eq!(img.get(0, 0) as f64, (fs * 0.95).round());
        assert_eq!(img.get(160, 128) as f64, fs.round());
    }

    #[test]
    fn ziggurat_draws_are_standard_normal() {
        let z = Ziggurat::new();
        // R and V are consistent: the recursion closes, the top layer's box (width
        // x[127], height 1 - f(x[127])) has area V like every other layer.
        let top = z.x[ZIG_LAYERS - 1];
        let top_area = top * (1.0 - (-0.5 * top * top).exp());
        assert!((top_area / ZIG_V - 1.0).abs() < 1e-6, "{top_area}");
        let mut rng = Rng::new(2024);
        let n = 1_000_000;
        let (mut m1, mut m2, mut m4) = (0.0, 0.0, 0.0);
        let (mut within1, mut beyond2, mut beyond3, mut beyond_r) = (0, 0, 0, 0);
        for _ in 0..n {
            let v = z.sample(&mut rng);
            m1 += v;
            m2 += v * v;
            m4 += v * v * v * v;
            within1 += (v.abs() < 1.0) as usize;
            beyond2 += (v.abs() > 2.0) as usize;
            beyond3 += (v.abs() > 3.0) as usize;
            beyond_r += (v.abs() > ZIG_R) as usize;
        }
        let nf = n as f64;
        let frac = |c: usize| c as f64 / nf;
        assert!((m1 / nf).abs() < 0.005, "mean {}", m1 / nf);
        assert!((m2 / nf - 1.0).abs() < 0.006, "variance {}", m2 / nf);
        assert!((m4 / nf - 3.0).abs() < 0.05, "fourth moment {}", m4 / nf);
        // Normal probabilities, tolerances about 5 standard errors.
        assert!(
            (frac(within1) - 0.682_689).abs() < 0.0025,
            "{}",
            frac(within1)
        );
        assert!(
            (frac(beyond2) - 0.045_500).abs() < 0.0011,
            "{}",
            frac(beyond2)
        );
        assert!(
            (frac(beyond3) - 0.002_700).abs() < 0.00026,
            "{}",
            frac(beyond3)
        );
        // The tail path is exercised: P(|x| > 3.4426) = 5.76e-4.
        assert!(
            (frac(beyond_r) - 5.76e-4).abs() < 1.3e-4,
            "{}",
            frac(beyond_r)
        );
    }

    #[test]
    fn kernel_is_normalised_and_skipped_when_negligible() {
        assert!(gaussian_kernel(0.04).is_none());
        assert!(gaussian_kernel(0.0).is_none());
        let k = gaussian_kernel(1.5).unwrap();
        assert_eq!(k.len(), 2 * 6 + 1);
        assert!((k.iter().sum::<f32>() - 1.0).abs() < 1e-6);
    }
}
