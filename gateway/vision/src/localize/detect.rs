//! Dot detection: find every complete calibration dot and measure its centre to a small
//! fraction of a pixel.
//!
//! Two stages, because the frame is large and the dots are few:
//!
//! 1. **Coarse** (`coarse`): sample the frame on a grid of stride `s` (chosen from the
//!    dot size so a dot spans about seven samples), threshold every sample against a
//!    local threshold (mid-way between the darkest and brightest sample of the
//!    surrounding blocks, so an illumination gradient or vignetting does not matter),
//!    and label connected components. Blobs touching the frame border, merged blobs and
//!    blobs whose area or shape is far from the median dot are dropped. This reads
//!    about 1/s² of the pixels.
//! 2. **Refine** (`refine_all`), reading only the pixels that carry information:
//!    * a background plane `B` is fitted on strips of pure background above and below
//!      each dot, and the dot level `F` on a square inside it;
//!    * the relative illumination gradient (`∇B/(B-o)`, `o` the black level) of every
//!      dot is smoothed over the frame with a low-order polynomial, because the slope of
//!      one dot's background is too noisy to use alone (see `smooth_gradients`);
//!    * the centre is the centroid of the background-normalised weight
//!      `w = (I - B(x)) / (F(x) - B(x))`, which cancels a multiplicative illumination
//!      gradient (uncorrected it biases a 60 px dot by ~0.04 px). Noise is never clamped
//!      (clamping biases the centroid towards the window centre). Instead, pixels
//!      certainly inside the dot get `w = 1` exactly and pixels certainly outside get
//!      `w = 0`, decided by their distance to the current centre estimate: both masks
//!      are symmetric about that estimate and agree with the true weights, so they add
//!      no bias, and only the thin edge band (where the position information is) adds
//!      noise (`Band`);
//!    * the band is placed by two horizontal chords (`chord_start`, ~0.1 px) and its
//!      width set from the frame's edge blur, measured with a wide pass on 9 dots
//!      (`frame_edge_sigma`); a dot whose band pass moves its centre by more than the
//!      band's margin gets further passes of its own.
//!
//! The per-dot work is done in sweeps over the frame's rows (`RowPlan`), all dots at
//! once, so the pixels are read in memory order.

use protocol::{MonoImage, Pixels, Polarity};

/// One detected dot, in pixel coordinates (integer = pixel centre).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Dot {
    /// Sub-pixel centre, x (right).
    pub x: f64,
    /// Sub-pixel centre, y (down).
    pub y: f64,
    /// Area in pixels, from the normalised weights (independent of blur and threshold).
    pub area_px: f64,
    /// Width of the edge transition (Gaussian sigma equivalent, pixels: optical blur
    /// plus pixel integration) used for this dot's band: the frame's, measured on a few
    /// dots, unless the dot needed passes of its own, which measure it.
    pub edge_sigma_px: f64,
    /// Dot level minus background level at the dot, grey levels (negative for dark dots).
    pub contrast: f64,
    /// RMS noise of the background around the dot, grey levels.
    pub noise: f64,
}

/// Sub-pixel centres of every complete dot in the frame.
///
/// Works for both polarities, 8- and 16-bit frames and dot diameters from about 8 to
/// 150 pixels without being told the scale (the sampling stride adapts to the dots it
/// finds). Dots cut by the frame border, merged blobs and blobs unlike the median dot
/// are not returned.
pub fn detect_dots(img: &MonoImage, polarity: Polarity) -> Vec<Dot> {
    detect_dots_sized(img, polarity, None)
}

/// [`detect_dots`] with the expected dot diameter in pixels, when the scale is known:
/// saves the first coarse pass that would otherwise find the dot size.
pub(crate) fn detect_dots_sized(
    img: &MonoImage,
    polarity: Polarity,
    dot_px: Option<f64>,
) -> Vec<Dot> {
    detect_dots_two_sizes(img, polarity, dot_px, 1.0)
}

/// [`detect_dots_sized`] for a board whose dots come in two sizes, the larger
/// `area_ratio` times the area of the smaller (a coded board): a dot is kept when its
/// area is like the median dot's, or `area_ratio` times larger or smaller.
pub(crate) fn detect_dots_two_sizes(
    img: &MonoImage,
    polarity: Polarity,
    dot_px: Option<f64>,
    area_ratio: f64,
) -> Vec<Dot> {
    let area_ratio = if area_ratio.is_finite() && area_ratio >= 1.0 {
        area_ratio
    } else {
        1.0
    };
    let (w, h) = (img.width as usize, img.height as usize);
    let full = img.max_value() as f64;
    let dark = polarity == Polarity::DarkOnLight;
    match &img.pixels {
        Pixels::Mono8(p) => match View::new(p, w, h) {
            Some(v) => detect_in(v, dark, dot_px, full, area_ratio),
            None => Vec::new(),
        },
        Pixels::Mono16(p) => match View::new(p, w, h) {
            Some(v) => detect_in(v, dark, dot_px, full, area_ratio),
            None => Vec::new(),
        },
    }
}

/// A pixel type the detector reads (8- or 16-bit grey).
pub(crate) trait Px: Copy {
    fn val(self) -> u32;
}

impl Px for u8 {
    #[inline(always)]
    fn val(self) -> u32 {
        self as u32
    }
}

impl Px for u16 {
    #[inline(always)]
    fn val(self) -> u32 {
        self as u32
    }
}

/// A row-major frame borrowed from a [`MonoImage`].
#[derive(Clone, Copy)]
pub(crate) struct View<'a, T> {
    data: &'a [T],
    w: usize,
    h: usize,
}

impl<'a, T: Px> View<'a, T> {
    /// None when the buffer does not hold `w*h` pixels (a malformed image).
    fn new(data: &'a [T], w: usize, h: usize) -> Option<Self> {
        (w > 0 && h > 0 && data.len() == w * h).then_some(Self { data, w, h })
    }

    #[inline(always)]
    fn row(&self, y: usize) -> &'a [T] {
        &self.data[y * self.w..(y + 1) * self.w]
    }
}

/// Coarse stride giving about seven samples across a dot of diameter `d` pixels.
fn stride_for(d: f64) -> usize {
    ((d / 7.0).floor() as usize).clamp(1, 16)
}

/// Threshold block size (in samples): a 3x3 neighbourhood of blocks spans about six dot
/// diameters, so it always holds both a whole dot and background for any board whose
/// pitch is up to ~4 dot diameters.
fn block_for(d: f64, s: usize) -> usize {
    ((2.2 * d / s as f64).ceil() as usize).clamp(4, 64)
}

fn detect_in<T: Px>(
    v: View<T>,
    dark: bool,
    dot_px: Option<f64>,
    full: f64,
    area_ratio: f64,
) -> Vec<Dot> {
    let (mut s, mut bs) = match dot_px {
        Some(d) if d.is_finite() && d > 0.0 => (stride_for(d), block_for(d, stride_for(d))),
        // Unknown scale: a first guess that finds dots from ~15 px up cheaply.
        _ => (6, 12),
    };
    let mut blobs = coarse(v, dark, s, bs, full);
    // Re-sample once if the first guess of stride or block size does not suit the dots
    // found: dots under ~4 samples across are poorly located and may be missed (when
    // none at all are found, they may be too small for the stride), and a neighbourhood
    // smaller than a few dots may lie entirely inside one.
    match median_diameter(&blobs) {
        Some(d) => {
            let too_coarse = d / (s as f64) < 4.0 && s > 1;
            let blocks_small = ((3 * bs * s) as f64) < 4.0 * d;
            if too_coarse || blocks_small {
                s = stride_for(d);
                bs = block_for(d, s);
                blobs = coarse(v, dark, s, bs, full);
            }
        }
        None if s > 2 => {
            s = 2;
            bs = 16;
            blobs = coarse(v, dark, s, bs, full);
        }
        None => {}
    }
    let blobs = filter_blobs(blobs, area_ratio);
    refine_all(v, dark, &blobs, s, area_ratio)
}

/// Is `area` within `lo..=hi` times the median area `med`, or (two dot sizes) within
/// that band around `med * ratio` or `med / ratio`?
fn like_median(area: f64, med: f64, lo: f64, hi: f64, ratio: f64) -> bool {
    let near = |m: f64| area >= lo * m && area <= hi * m;
    near(med) || (ratio > 1.0 && (near(med * ratio) || near(med / ratio)))
}

fn median_diameter(blobs: &[Blob]) -> Option<f64> {
    let mut a: Vec<f64> = blobs.iter().filter(|b| !b.border).map(|b| b.area).collect();
    let m = median(&mut a)?;
    Some(2.0 * (m / std::f64::consts::PI).sqrt())
}

/// Median of a slice (reordered in place); None when empty.
pub(crate) fn median(v: &mut [f64]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    let mid = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(mid, |a, b| a.total_cmp(b));
    Some(*m)
}

/// A connected component of the coarse grid, in pixel units.
#[derive(Clone, Copy, Debug)]
struct Blob {
    x: f64,
    y: f64,
    area: f64,
    /// Axis ratio of the second-moment ellipse (1 for a disc).
    elong: f64,
    /// Number of samples.
    n: usize,
    /// Touches the edge of the sampled grid (the dot may be cut by the frame).
    border: bool,
}

#[derive(Clone, Copy)]
struct Run {
    y: u32,
    x0: u32,
    x1: u32,
}

fn find(parent: &mut [u32], mut i: u32) -> u32 {
    while parent[i as usize] != i {
        let p = parent[parent[i as usize] as usize];
        parent[i as usize] = p;
        i = p;
    }
    i
}

/// Stage 1: threshold a stride-`s` sample grid locally and label 8-connected components.
fn coarse<T: Px>(v: View<T>, dark: bool, s: usize, bs: usize, full: f64) -> Vec<Blob> {
    let off = (s - 1) / 2;
    if v.w <= off + 2 * s || v.h <= off + 2 * s {
        return Vec::new();
    }
    let nx = (v.w - 1 - off) / s + 1;
    let ny = (v.h - 1 - off) / s + 1;
    let mut g: Vec<u32> = Vec::with_capacity(nx * ny);
    for gy in 0..ny {
        let row = v.row(off + gy * s);
        g.extend(row[off..].iter().step_by(s).take(nx).map(|p| p.val()));
    }

    // Pixel noise from horizontal neighbour differences on a few rows (robust median;
    // edges are a minority). Used only to tell real contrast from noise.
    let mut diffs: Vec<f64> = Vec::with_capacity(nx * ny.div_ceil(8));
    for gy in (0..ny).step_by(8) {
        let row = v.row(off + gy * s);
        for gx in 0..nx {
            let x = off + gx * s;
            if x + 1 < v.w {
                diffs.push(row[x + 1].val().abs_diff(row[x].val()) as f64);
            }
        }
    }
    let noise = (median(&mut diffs).unwrap_or(0.0) * 1.4826 / std::f64::consts::SQRT_2).max(0.5);

    // Block extremes, then a 3x3 neighbourhood: a threshold mid-way between the local
    // dot and background levels, valid only where the contrast is well above noise.
    let nbx = nx.div_ceil(bs);
    let nby = ny.div_ceil(bs);
    let mut bmin = vec![u32::MAX; nbx * nby];
    let mut bmax = vec![0u32; nbx * nby];
    for gy in 0..ny {
        let by = gy / bs;
        for (bx, chunk) in g[gy * nx..(gy + 1) * nx].chunks(bs).enumerate() {
            let (mn, mx) = chunk
                .iter()
                .fold((u32::MAX, 0u32), |(a, b), &x| (a.min(x), b.max(x)));
            let k = by * nbx + bx;
            bmin[k] = bmin[k].min(mn);
            bmax[k] = bmax[k].max(mx);
        }
    }
    let min_contrast = (12.0 * noise).max(0.02 * full);
    let mut thr = vec![f64::NAN; nbx * nby];
    for by in 0..nby {
        for bx in 0..nbx {
            let (mut lo, mut hi) = (u32::MAX, 0u32);
            for yy in by.saturating_sub(1)..(by + 2).min(nby) {
                for xx in bx.saturating_sub(1)..(bx + 2).min(nbx) {
                    lo = lo.min(bmin[yy * nbx + xx]);
                    hi = hi.max(bmax[yy * nbx + xx]);
                }
            }
            if hi >= lo && (hi - lo) as f64 >= min_contrast {
                thr[by * nbx + bx] = 0.5 * (lo as f64 + hi as f64);
            }
        }
    }
    if !fill_missing(&mut thr, nbx, nby) {
        return Vec::new();
    }

    // Integer thresholds: for dark dots `v < ceil(t)` is `v < t`, for bright ones
    // `v > floor(t)` is `v > t`.
    let thr_i: Vec<u32> = thr
        .iter()
        .map(|&t| {
            if dark {
                t.ceil() as u32
            } else {
                t.floor() as u32
            }
        })
        .collect();

    // Runs of dot samples per row, joined across rows with union-find.
    let mut runs: Vec<Run> = Vec::new();
    let mut row_start = Vec::with_capacity(ny + 1);
    let mut on_row = vec![false; nx];
    for gy in 0..ny {
        row_start.push(runs.len());
        let by = gy / bs;
        let row = &g[gy * nx..(gy + 1) * nx];
        for ((bx, chunk), mask) in row.chunks(bs).enumerate().zip(on_row.chunks_mut(bs)) {
            let t = thr_i[by * nbx + bx];
            for (m, &val) in mask.iter_mut().zip(chunk) {
                *m = if dark { val < t } else { val > t };
            }
        }
        let mut gx = 0;
        while gx < nx {
            if !on_row[gx] {
                gx += 1;
                continue;
            }
            let x0 = gx;
            while gx < nx && on_row[gx] {
                gx += 1;
            }
            runs.push(Run {
                y: gy as u32,
                x0: x0 as u32,
                x1: gx as u32 - 1,
            });
        }
    }
    row_start.push(runs.len());
    let mut parent: Vec<u32> = (0..runs.len() as u32).collect();
    for gy in 1..ny {
        let (a0, a1) = (row_start[gy - 1], row_start[gy]);
        let mut i = a0;
        for j in row_start[gy]..row_start[gy + 1] {
            let r = runs[j];
            while i < a1 && runs[i].x1 + 1 < r.x0 {
                i += 1;
            }
            let mut k = i;
            while k < a1 && runs[k].x0 <= r.x1 + 1 {
                let (ra, rb) = (find(&mut parent, k as u32), find(&mut parent, j as u32));
                if ra != rb {
                    parent[ra.max(rb) as usize] = ra.min(rb);
                }
                k += 1;
            }
        }
    }

    // Moments per component.
    #[derive(Clone, Copy, Default)]
    struct Acc {
        n: f64,
        sx: f64,
        sy: f64,
        sxx: f64,
        syy: f64,
        sxy: f64,
        border: bool,
    }
    let sq = |m: f64| m * (m + 1.0) * (2.0 * m + 1.0) / 6.0;
    let mut acc: Vec<Acc> = vec![Acc::default(); runs.len()];
    for (k, r) in runs.iter().enumerate() {
        let root = find(&mut parent, k as u32) as usize;
        let (x0, x1, y) = (r.x0 as f64, r.x1 as f64, r.y as f64);
        let n = x1 - x0 + 1.0;
        let sx = 0.5 * (x0 + x1) * n;
        let a = &mut acc[root];
        a.n += n;
        a.sx += sx;
        a.sy += y * n;
        a.sxx += sq(x1) - sq(x0 - 1.0);
        a.syy += y * y * n;
        a.sxy += y * sx;
        a.border |= r.x0 == 0 || r.x1 as usize == nx - 1 || r.y == 0 || r.y as usize == ny - 1;
    }
    let (sf, of) = (s as f64, off as f64);
    acc.iter()
        .filter(|a| a.n >= 3.0)
        .map(|a| {
            let (mx, my) = (a.sx / a.n, a.sy / a.n);
            let vxx = a.sxx / a.n - mx * mx;
            let vyy = a.syy / a.n - my * my;
            let vxy = a.sxy / a.n - mx * my;
            let tr = 0.5 * (vxx + vyy);
            let det = (0.25 * (vxx - vyy).powi(2) + vxy * vxy).sqrt();
            let (l1, l2) = (tr + det, tr - det);
            let elong = if l2 > 0.0 {
                (l1 / l2).sqrt()
            } else {
                f64::INFINITY
            };
            Blob {
                x: of + sf * mx,
                y: of + sf * my,
                area: a.n * sf * sf,
                elong,
                n: a.n as usize,
                border: a.border,
            }
        })
        .collect()
}

/// Fill NaN thresholds from valid neighbours (blocks lying wholly in background or
/// wholly inside a big dot have no contrast of their own). False if nothing is valid.
fn fill_missing(thr: &mut [f64], nbx: usize, nby: usize) -> bool {
    if thr.iter().all(|t| t.is_nan()) {
        return false;
    }
    loop {
        let mut missing = false;
        let prev = thr.to_vec();
        for by in 0..nby {
            for bx in 0..nbx {
                if !prev[by * nbx + bx].is_nan() {
                    continue;
                }
                let (mut sum, mut cnt) = (0.0, 0.0);
                for yy in by.saturating_sub(1)..(by + 2).min(nby) {
                    for xx in bx.saturating_sub(1)..(bx + 2).min(nbx) {
                        let t = prev[yy * nbx + xx];
                        if !t.is_nan() {
                            sum += t;
                            cnt += 1.0;
                        }
                    }
                }
                if cnt > 0.0 {
                    thr[by * nbx + bx] = sum / cnt;
                } else {
                    missing = true;
                }
            }
        }
        if !missing {
            return true;
        }
    }
}

/// Drop border blobs, merged blobs and blobs unlike the median dot.
fn filter_blobs(blobs: Vec<Blob>, area_ratio: f64) -> Vec<Blob> {
    let mut areas: Vec<f64> = blobs.iter().filter(|b| !b.border).map(|b| b.area).collect();
    let Some(med) = median(&mut areas) else {
        return Vec::new();
    };
    blobs
        .into_iter()
        .filter(|b| {
            !b.border
                && like_median(b.area, med, 0.5, 1.6, area_ratio)
                // Small blobs are too coarsely sampled for a shape test.
                && (b.n < 12 || b.elong <= 1.6)
        })
        .collect()
}

/// Uniform-grid spatial index for nearest-neighbour queries on a few hundred points.
pub(crate) struct SpatialGrid {
    cell: f64,
    x0: f64,
    y0: f64,
    nx: usize,
    ny: usize,
    start: Vec<usize>,
    items: Vec<usize>,
}

impl SpatialGrid {
    pub(crate) fn new(pts: &[[f64; 2]], cell: f64) -> Self {
        let cell = if cell.is_finite() && cell > 0.0 {
            cell
        } else {
            1.0
        };
        let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
        for p in pts {
            x0 = x0.min(p[0]);
            y0 = y0.min(p[1]);
            x1 = x1.max(p[0]);
            y1 = y1.max(p[1]);
        }
        if pts.is_empty() {
            (x0, y0, x1, y1) = (0.0, 0.0, 0.0, 0.0);
        }
        let nx = (((x1 - x0) / cell) as usize + 1).min(4096);
        let ny = (((y1 - y0) / cell) as usize + 1).min(4096);
        let mut g = Self {
            cell,
            x0,
            y0,
            nx,
            ny,
            start: vec![0; nx * ny + 1],
            items: vec![0; pts.len()],
        };
        for p in pts {
            let c = g.cell_of(*p);
            g.start[c + 1] += 1;
        }
        for k in 0..nx * ny {
            g.start[k + 1] += g.start[k];
        }
        let mut fill = g.start.clone();
        for (i, p) in pts.iter().enumerate() {
            let c = g.cell_of(*p);
            g.items[fill[c]] = i;
            fill[c] += 1;
        }
        g
    }

    fn cell_xy(&self, p: [f64; 2]) -> (usize, usize) {
        let cx = (((p[0] - self.x0) / self.cell).max(0.0) as usize).min(self.nx - 1);
        let cy = (((p[1] - self.y0) / self.cell).max(0.0) as usize).min(self.ny - 1);
        (cx, cy)
    }

    fn cell_of(&self, p: [f64; 2]) -> usize {
        let (cx, cy) = self.cell_xy(p);
        cy * self.nx + cx
    }

    /// Up to `k` nearest other points of point `i` within `max_dist`, nearest first,
    /// as (distance, index).
    pub(crate) fn knn(
        &self,
        pts: &[[f64; 2]],
        i: usize,
        k: usize,
        max_dist: f64,
    ) -> Vec<(f64, usize)> {
        let q = pts[i];
        let (cx, cy) = self.cell_xy(q);
        let mut best: Vec<(f64, usize)> = Vec::with_capacity(k + 1);
        let max_ring = self.nx.max(self.ny);
        for ring in 0..=max_ring {
            // Every point in this ring or beyond is at least (ring-1) cells away.
            let reach = (ring as f64 - 1.0).max(0.0) * self.cell;
            if reach > max_dist || (best.len() == k && best[k - 1].0 <= reach) {
                break;
            }
            let (xa, xb) = (cx as i64 - ring as i64, cx as i64 + ring as i64);
            let (ya, yb) = (cy as i64 - ring as i64, cy as i64 + ring as i64);
            for yy in ya..=yb {
                if yy < 0 || yy >= self.ny as i64 {
                    continue;
                }
                let on_edge_row = yy == ya || yy == yb;
                let mut xx = xa;
                while xx <= xb {
                    if xx >= 0 && xx < self.nx as i64 {
                        let c = yy as usize * self.nx + xx as usize;
                        for &j in &self.items[self.start[c]..self.start[c + 1]] {
                            if j == i {
                                continue;
                            }
                            let d =
                                ((pts[j][0] - q[0]).powi(2) + (pts[j][1] - q[1]).powi(2)).sqrt();
                            if d <= max_dist && (best.len() < k || d < best[k - 1].0) {
                                let pos = best.partition_point(|e| e.0 <= d);
                                best.insert(pos, (d, j));
                                best.truncate(k);
                            }
                        }
                    }
                    // Inner rows of the ring: only the two edge columns are new.
                    xx = if on_edge_row || xx == xb { xx + 1 } else { xb };
                }
            }
        }
        best
    }
}

/// Least-squares plane accumulator over pixels, coordinates relative to (px, py).
#[derive(Clone, Copy, Default, Debug)]
struct PlaneAcc {
    n: f64,
    sx: f64,
    sy: f64,
    sxx: f64,
    syy: f64,
    sxy: f64,
    si: f64,
    six: f64,
    siy: f64,
    sii: f64,
}

/// A fitted plane `v = b0 + gx (x - px) + gy (y - py)` with the variances of the slopes.
#[derive(Clone, Copy, Debug)]
struct PlaneFit {
    b0: f64,
    gx: f64,
    gy: f64,
    var_gx: f64,
    var_gy: f64,
    sigma: f64,
}

impl PlaneAcc {
    /// Add pixels `x in [xa, xb]` of row `y` (offsets from the plane origin `dx`, `dy`).
    #[inline]
    fn add_segment<T: Px>(&mut self, row: &[T], xa: usize, xb: usize, dxa: i64, dy: i64) {
        let [s0, s1, _, s2] = run_sums::<T, false, true>(&row[xa..=xb]);
        let n = (xb - xa + 1) as f64;
        let a = dxa as f64;
        let b = a + n - 1.0;
        let sq = |m: f64| m * (m + 1.0) * (2.0 * m + 1.0) / 6.0;
        let sdx = 0.5 * (a + b) * n;
        let dyf = dy as f64;
        self.n += n;
        self.sx += sdx;
        self.sy += dyf * n;
        self.sxx += sq(b) - sq(a - 1.0);
        self.syy += dyf * dyf * n;
        self.sxy += dyf * sdx;
        self.si += s0;
        let six = s1 + a * s0;
        self.six += six;
        self.siy += dyf * s0;
        self.sii += s2;
    }

    fn solve(&self) -> Option<PlaneFit> {
        if self.n < 6.0 {
            return None;
        }
        let m = nalgebra::Matrix3::new(
            self.n, self.sx, self.sy, self.sx, self.sxx, self.sxy, self.sy, self.sxy, self.syy,
        );
        let inv = m.try_inverse()?;
        let rhs = nalgebra::Vector3::new(self.si, self.six, self.siy);
        let beta = inv * rhs;
        let rss = (self.sii - beta.dot(&rhs)).max(0.0);
        // Never below the quantisation variance (1/12 LSB²): a noise-free flat region
        // quantises to one value, which would fake a perfectly known zero slope.
        let var = (rss / (self.n - 3.0)).max(1.0 / 12.0);
        Some(PlaneFit {
            b0: beta[0],
            gx: beta[1],
            gy: beta[2],
            var_gx: var * inv[(1, 1)],
            var_gy: var * inv[(2, 2)],
            sigma: var.sqrt(),
        })
    }
}

/// Per-dot background/foreground measurements before the centroid passes.
#[derive(Clone, Copy, Debug)]
struct Prep {
    c0: [f64; 2],
    r0: f64,
    /// Initial position uncertainty (pixels).
    e0: f64,
    /// Initial edge half-width guess (pixels).
    h0: f64,
    /// Distance to the nearest other blob.
    nn: f64,
    px: i64,
    py: i64,
    ring: PlaneFit,
    inner: Option<PlaneFit>,
    /// Mean of the 3x3 pixels at (px, py): the dot level of a dot too small for an
    /// interior square.
    f_centre: f64,
}

/// The illumination model at one dot: `B(x) = b0 + (b0 - o) g·(x - p)` and
/// `F(x) - B(x) = d0 (1 + g·(x - p))`, with `g` the relative illumination gradient.
#[derive(Clone, Copy, Debug)]
struct Illum {
    px: i64,
    py: i64,
    b0: f64,
    bl: f64,
    g: [f64; 2],
    d0: f64,
}

fn refine_all<T: Px>(
    v: View<T>,
    dark: bool,
    blobs: &[Blob],
    s: usize,
    area_ratio: f64,
) -> Vec<Dot> {
    if blobs.is_empty() {
        return Vec::new();
    }
    let pts: Vec<[f64; 2]> = blobs.iter().map(|b| [b.x, b.y]).collect();
    let mut areas: Vec<f64> = blobs.iter().map(|b| b.area).collect();
    let med_area = median(&mut areas).unwrap_or(1.0);
    let grid = SpatialGrid::new(&pts, 2.0 * med_area.sqrt());
    let e0 = 0.5 * s as f64 + 1.0;

    // Geometry of every blob's background strips and interior square.
    struct Geo {
        c0: [f64; 2],
        r0: f64,
        h0: f64,
        nn: f64,
        px: i64,
        py: i64,
        /// Background rows |dy| in [a1, a2] (every `step`-th), columns px ± a2.
        a1: i64,
        a2: i64,
        /// Interior square half-size (0: none).
        ri: i64,
        step: i64,
    }
    let geos: Vec<Geo> = blobs
        .iter()
        .enumerate()
        .map(|(i, b)| {
            let r0 = (b.area / std::f64::consts::PI).sqrt();
            let nn = grid
                .knn(&pts, i, 1, f64::MAX)
                .first()
                .map_or(f64::INFINITY, |e| e.0);
            let h0 = 2.5 + 0.1 * r0;
            let k = r0 + h0 + e0;
            let mut r1 = k + 1.0;
            let mut r2 = (nn - k - 1.0).min(r1 + (0.5 * r0).max(6.0));
            if r2 < r1 + 2.0 {
                // Crowded dots: take the background from the middle of the gap.
                r1 = (0.5 * nn - 1.0).max(r0 + 1.0);
                r2 = r1 + 2.0;
            }
            // Sparse rows: the slope is smoothed over all dots afterwards, and the
            // level only sets how fast the centroid passes converge.
            let step = ((r0 / 8.0) as i64).clamp(1, 4);
            // The interior: the square inscribed in the certainly-inside disc.
            let ri = ((r0 - h0 - e0) / std::f64::consts::SQRT_2).floor() as i64;
            Geo {
                c0: [b.x, b.y],
                r0,
                h0,
                nn,
                px: b.x.round() as i64,
                py: b.y.round() as i64,
                a1: r1.ceil() as i64,
                a2: r2.floor() as i64,
                ri: if ri >= 2 { ri } else { 0 },
                step,
            }
        })
        .collect();

    // One sweep over the rows: background strips (two per dot, above and below, as
    // wide as the ring: any background pixels do for a plane, and long rows are cheap
    // to sum) and interior squares.
    let mut pairs: Vec<(i64, u32)> = Vec::new();
    for (i, g) in geos.iter().enumerate() {
        for d in (g.a1..=g.a2).step_by(g.step as usize) {
            pairs.push((g.py - d, 2 * i as u32));
            pairs.push((g.py + d, 2 * i as u32));
        }
        if g.ri > 0 {
            for d in (-g.ri..=g.ri).step_by(g.step as usize) {
                pairs.push((g.py + d, 2 * i as u32 + 1));
            }
        }
    }
    let mut accs = vec![PlaneAcc::default(); 2 * geos.len()];
    let half = |g: &Geo, item: u32| if item & 1 == 0 { g.a2 } else { g.ri };
    let touch = |y: usize| touch_row(v.row(y));
    RowPlan::new(v.h, &pairs).for_each(touch, |y, item| {
        let g = &geos[item as usize / 2];
        let h = half(g, item);
        let xa = (g.px - h).max(0);
        let xb = (g.px + h).min(v.w as i64 - 1);
        if xb >= xa {
            accs[item as usize].add_segment(
                v.row(y),
                xa as usize,
                xb as usize,
                xa - g.px,
                y as i64 - g.py,
            );
        }
    });
    let preps: Vec<Prep> = geos
        .iter()
        .enumerate()
        .filter_map(|(i, g)| {
            let ring = accs[2 * i].solve()?;
            let inner = if g.ri > 0 {
                accs[2 * i + 1].solve()
            } else {
                None
            };
            let (x, y) = (
                g.px.clamp(1, v.w as i64 - 2) as usize,
                g.py.clamp(1, v.h as i64 - 2) as usize,
            );
            let f_centre = (y - 1..=y + 1)
                .map(|yy| {
                    v.row(yy)[x - 1..=x + 1]
                        .iter()
                        .map(|p| p.val() as f64)
                        .sum::<f64>()
                })
                .sum::<f64>()
                / 9.0;
            Some(Prep {
                c0: g.c0,
                r0: g.r0,
                e0,
                h0: g.h0,
                nn: g.nn,
                px: g.px,
                py: g.py,
                ring,
                inner,
                f_centre,
            })
        })
        .collect();
    if preps.is_empty() {
        return Vec::new();
    }

    let levels = level_relation(&preps);
    // Black level o: where F and B would meet (F - o = kappa (B - o)).
    let o = match levels {
        Some((a, kappa)) if (1.0 - kappa).abs() > 1e-3 => a / (1.0 - kappa),
        _ => 0.0,
    };
    let gs = smooth_gradients(&preps, o, [v.w as f64, v.h as f64]);

    // Illumination at every dot; dots of the wrong polarity or with contrast lost in
    // noise are not dots.
    let cands: Vec<(&Prep, Illum)> = preps
        .iter()
        .zip(gs)
        .filter_map(|(p, g)| {
            let b0 = p.ring.b0;
            // Dot level: its interior, else the frame's level relation, else the
            // centre pixels (tiny dots; blur may keep them short of the true level,
            // which only slows the centroid's convergence).
            let f0 = match (p.inner, levels) {
                (Some(f), _) => f.b0,
                (None, Some((a, kappa))) => a + kappa * b0,
                (None, None) => p.f_centre,
            };
            let d0 = f0 - b0;
            let wrong = (dark && d0 >= 0.0) || (!dark && d0 <= 0.0);
            (!wrong && d0.abs() >= 6.0 * p.ring.sigma.max(0.5)).then_some((
                p,
                Illum {
                    px: p.px,
                    py: p.py,
                    b0,
                    bl: b0 - o,
                    g,
                    d0,
                },
            ))
        })
        .collect();
    let sig_frame = frame_edge_sigma(v, &cands);

    // Where each dot's narrow band goes: chords + the frame's edge width, or the wide
    // pass when either is missing.
    let starts: Vec<Option<Start>> = cands
        .iter()
        .map(|(p, il)| match (sig_frame, chord_start(v, p, il)) {
            (Some(sig), Some((c, r))) => Some(Start { c, r, sig }),
            _ => wide_pass(v, p, il).map(|(c, sig, r)| Start { c, r, sig }),
        })
        .collect();
    // All narrow bands in one sweep over the rows.
    let mut bands: Vec<Option<Band>> = cands
        .iter()
        .zip(&starts)
        .map(|((p, il), st)| st.and_then(|st| st.band(v, p, il)))
        .collect();
    let mut pairs: Vec<(i64, u32)> = Vec::new();
    for (k, b) in bands.iter().enumerate() {
        if let Some(b) = b {
            let (y0, y1) = b.rows();
            pairs.extend((y0..=y1).map(|y| (y, k as u32)));
        }
    }
    let touch = |y: usize| touch_row(v.row(y));
    RowPlan::new(v.h, &pairs).for_each(touch, |y, k| {
        if let Some(b) = &mut bands[k as usize] {
            b.add_row::<T, false>(v.row(y), y as i64);
        }
    });
    let mut dots: Vec<Dot> = cands
        .iter()
        .zip(starts.iter().zip(&bands))
        .filter_map(|((p, il), (st, b))| finish_dot(v, p, il, (*st)?, b.as_ref()?.finish(1)?))
        .collect();

    // Final consistency: refined areas are exact, so a dot far from the median is
    // damaged, dirty or two dots.
    let mut areas: Vec<f64> = dots.iter().map(|d| d.area_px).collect();
    if let Some(med) = median(&mut areas) {
        dots.retain(|d| like_median(d.area_px, med, 0.7, 1.4, area_ratio));
    }
    dots
}

/// Dot level as a function of background level over all dots, `F = a + kappa B`
/// (a straight line through the illumination variation; `a` is the sensor's black
/// level times (1 - kappa)). When the illumination is nearly flat the slope is pulled
/// to the pure multiplicative model `a = 0`.
fn level_relation(preps: &[Prep]) -> Option<(f64, f64)> {
    let pairs: Vec<(f64, f64)> = preps
        .iter()
        .filter_map(|p| p.inner.map(|f| (p.ring.b0, f.b0)))
        .collect();
    let mut ratios: Vec<f64> = pairs
        .iter()
        .filter(|(b, _)| b.abs() > 1e-9)
        .map(|(b, f)| f / b)
        .collect();
    let k0 = median(&mut ratios)?;
    let n = pairs.len() as f64;
    let bm = pairs.iter().map(|p| p.0).sum::<f64>() / n;
    let fm = pairs.iter().map(|p| p.1).sum::<f64>() / n;
    let (mut sxy, mut sxx) = (0.0, 0.0);
    for (b, f) in &pairs {
        sxy += (b - bm) * (f - fm);
        sxx += (b - bm) * (b - bm);
    }
    // Ridge weight: as if kappa0 were supported by a 2 % spread of background levels.
    let lambda = n * (0.02 * bm).powi(2);
    let kappa = (sxy + lambda * k0) / (sxx + lambda);
    Some((fm - kappa * bm, kappa))
}

/// Relative illumination gradient `g = ∇B/(B-o)` at every dot, from the background
/// slope smoothed over the frame.
///
/// Each dot gives the background slope `∇B` from its strips and, from its interior,
/// `∇F (B-o)/(F-o)` (the same slope if the illumination is multiplicative), inverse-
/// variance weighted. One dot's slope is noisy (on a 60 px dot with 4 grey levels of
/// noise it moves the centre by ~0.002 px, and on bright-on-dark boards, where `B-o`
/// is small, by ~0.01 px), while real illumination is smooth: so `∇B` is fitted as a
/// low-order polynomial in frame position (quadratic with at least 30 dots, linear
/// with at least 6), with outliers (dirt) trimmed. `∇B` rather than `g`: a linear gradient plus
/// quadratic vignetting has an exactly linear `∇B`, whereas `g` has the illumination
/// in its denominator and is far from polynomial when the illumination varies a lot.
fn smooth_gradients(preps: &[Prep], o: f64, size: [f64; 2]) -> Vec<[f64; 2]> {
    // Per-dot estimates of ∇B with their weights (inverse variances).
    let est: Vec<([f64; 2], [f64; 2])> = preps
        .iter()
        .map(|p| {
            let mut acc = [(0.0, 0.0); 2];
            let mut add = |f: &PlaneFit, scale: f64| {
                for (c, (gv, var)) in [(f.gx, f.var_gx), (f.gy, f.var_gy)].into_iter().enumerate() {
                    let (gr, vr) = (gv * scale, (var * scale * scale).max(1e-30));
                    acc[c].0 += gr / vr;
                    acc[c].1 += 1.0 / vr;
                }
            };
            add(&p.ring, 1.0);
            if let Some(f) = &p.inner {
                let lf = f.b0 - o;
                if lf.abs() > 1e-9 {
                    add(f, (p.ring.b0 - o) / lf);
                }
            }
            let g = [
                acc[0].0 / acc[0].1.max(1e-300),
                acc[1].0 / acc[1].1.max(1e-300),
            ];
            (g, [acc[0].1, acc[1].1])
        })
        .collect();
    // ∇B -> g at each dot.
    let rel = |k: usize, grad: [f64; 2]| {
        let l = preps[k].ring.b0 - o;
        if l.abs() > 1e-9 {
            [grad[0] / l, grad[1] / l]
        } else {
            [0.0, 0.0]
        }
    };
    let n = preps.len();
    // Vignetting makes g vary linearly across the frame, so never less than a plane;
    // with very few dots (which are then large, with precise rings of their own) use
    // each dot's own estimate.
    let nterms = if n >= 30 {
        6
    } else if n >= 6 {
        3
    } else {
        return est.iter().enumerate().map(|(k, e)| rel(k, e.0)).collect();
    };
    let basis = |c: [f64; 2]| -> [f64; 6] {
        let u = (c[0] - 0.5 * size[0]) / (0.5 * size[0]);
        let v = (c[1] - 0.5 * size[1]) / (0.5 * size[1]);
        [1.0, u, v, u * u, u * v, v * v]
    };
    let mut out = vec![[0.0; 2]; n];
    for comp in 0..2 {
        let mut keep = vec![true; n];
        let mut coef = nalgebra::DVector::<f64>::zeros(nterms);
        for round in 0..2 {
            let mut ata = nalgebra::DMatrix::<f64>::zeros(nterms, nterms);
            let mut atb = nalgebra::DVector::<f64>::zeros(nterms);
            for (k, p) in preps.iter().enumerate() {
                if !keep[k] {
                    continue;
                }
                let b = basis(p.c0);
                let (gv, wv) = (est[k].0[comp], est[k].1[comp]);
                for r in 0..nterms {
                    atb[r] += wv * b[r] * gv;
                    for c in 0..nterms {
                        ata[(r, c)] += wv * b[r] * b[c];
                    }
                }
            }
            match ata.clone().cholesky() {
                Some(ch) => coef = ch.solve(&atb),
                None => break,
            }
            if round == 0 {
                // Trim estimates more than 4 robust sigmas from the smooth model (the
                // scale is measured, not taken from the variances, which ignore any
                // mismatch of the polynomial).
                let z: Vec<f64> = preps
                    .iter()
                    .enumerate()
                    .map(|(k, p)| {
                        let b = basis(p.c0);
                        let m: f64 = (0..nterms).map(|r| coef[r] * b[r]).sum();
                        (est[k].0[comp] - m) * est[k].1[comp].sqrt()
                    })
                    .collect();
                let mut az: Vec<f64> = z.iter().map(|v| v.abs()).collect();
                let scale = 1.4826 * median(&mut az).unwrap_or(0.0);
                for k in 0..n {
                    keep[k] = z[k].abs() <= 4.0 * scale.max(1.0);
                }
            }
        }
        for (k, p) in preps.iter().enumerate() {
            let b = basis(p.c0);
            out[k][comp] = (0..nterms).map(|r| coef[r] * b[r]).sum();
        }
    }
    out.iter().enumerate().map(|(k, g)| rel(k, *g)).collect()
}

/// Result of one centroid pass.
#[derive(Clone, Copy, Debug)]
struct PassOut {
    c: [f64; 2],
    area: f64,
    /// Σ w (1 - w) over the edge band (partial-coverage mass), scaled to all rows.
    w1w: f64,
    /// Number of edge-band pixels, scaled to all rows.
    n_edge: f64,
}

/// `floor` without a libm call (SSE2 has no rounding instruction).
#[inline(always)]
fn ffloor(x: f64) -> i64 {
    let i = x as i64;
    if (i as f64) > x {
        i - 1
    } else {
        i
    }
}

/// `ceil` without a libm call.
#[inline(always)]
fn fceil(x: f64) -> i64 {
    let i = x as i64;
    if (i as f64) < x {
        i + 1
    } else {
        i
    }
}

/// Exact sums over a run of pixels: Σv, Σv·k, Σv·k² (when `K2`; k = 0.. along the
/// run) and Σv² (when `SQ`).
///
/// The k-weighted sums need no multiplication: with repeated prefix sums
/// P = Σ_{j<=m} v_j, Q = Σ_{j<=m} P_j, R = Σ_{j<=m} Q_j taken to the run's end,
/// Q = Σ v u and R = Σ v u(u+1)/2 with u = L - k, from which Σv·k and Σv·k² follow.
/// Three integer additions per pixel (plus one multiply-add for Σv²): this loop is
/// most of the localizer's time. u64 cannot overflow for runs under ~10^5 pixels.
#[inline(always)]
fn run_sums<T: Px, const K2: bool, const SQ: bool>(px: &[T]) -> [f64; 4] {
    let (mut p, mut q, mut r, mut sq) = (0u64, 0u64, 0u64, 0u64);
    for x in px {
        let v = x.val() as u64;
        p += v;
        q += p;
        if K2 {
            r += q;
        }
        if SQ {
            sq += v * v;
        }
    }
    let l = px.len() as u64;
    let s1 = l * p - q; // Σ v (l - u)
                        // Σ v (l - u)² = l² Σv - 2 l Σvu + Σvu², with Σvu² = 2R - Q.
    let s2 = if K2 {
        l * l * p + 2 * r - q - 2 * l * q
    } else {
        0
    };
    // Via i64: a signed conversion is one instruction, an unsigned one is not.
    [
        p as i64 as f64,
        s1 as i64 as f64,
        s2 as i64 as f64,
        sq as i64 as f64,
    ]
}

/// Work on many dots grouped by image row (a counting sort), so that a stage reads the
/// frame in one forward sweep.
///
/// Why: visiting dot after dot, each row of each dot is a cache miss whose latency is
/// not overlapped with anything (the per-row arithmetic fills the out-of-order window);
/// on a 2448x2048 16-bit frame that cost more than the arithmetic. In row order the
/// accesses stream through memory and the hardware prefetcher hides the latency.
struct RowPlan {
    start: Vec<u32>,
    items: Vec<u32>,
}

impl RowPlan {
    /// `pairs` = (row, item); rows outside `0..h` are dropped. Items keep their order
    /// within a row.
    fn new(h: usize, pairs: &[(i64, u32)]) -> Self {
        let mut start = vec![0u32; h + 1];
        for &(y, _) in pairs {
            if y >= 0 && (y as usize) < h {
                start[y as usize + 1] += 1;
            }
        }
        for y in 0..h {
            start[y + 1] += start[y];
        }
        let mut fill = start.clone();
        let mut items = vec![0u32; start[h] as usize];
        for &(y, it) in pairs {
            if y >= 0 && (y as usize) < h {
                items[fill[y as usize] as usize] = it;
                fill[y as usize] += 1;
            }
        }
        Self { start, items }
    }

    /// Call `f(row, item)` for every pair in row order. Before each row, `touch(row)`
    /// is called for the row `AHEAD` rows further on (if it has items): it should read
    /// one pixel per cache line of that row. Those reads depend on nothing, so the
    /// processor keeps many in flight and the prefetcher sees one sequential stream;
    /// by the time `f` gets to the row, its pixels are in cache. (Without it, most of
    /// the time went into waiting for the first pixel of each run; touching only the
    /// items' own spans helped less than whole rows.)
    fn for_each(&self, mut touch: impl FnMut(usize) -> u32, mut f: impl FnMut(usize, u32)) {
        const AHEAD: usize = 4;
        let rows = self.start.len() - 1;
        let items = |y: usize| &self.items[self.start[y] as usize..self.start[y + 1] as usize];
        let mut sink = 0u32;
        for y in 0..AHEAD.min(rows) {
            if !items(y).is_empty() {
                sink = sink.wrapping_add(touch(y));
            }
        }
        for y in 0..rows {
            if y + AHEAD < rows && !items(y + AHEAD).is_empty() {
                sink = sink.wrapping_add(touch(y + AHEAD));
            }
            for &it in items(y) {
                f(y, it);
            }
        }
        std::hint::black_box(sink);
    }
}

/// Read one pixel per cache line of a row (see `RowPlan::for_each`).
#[inline]
fn touch_row<T: Px>(row: &[T]) -> u32 {
    let step = (64 / std::mem::size_of::<T>()).max(1);
    row.iter()
        .step_by(step)
        .fold(0u32, |a, p| a.wrapping_add(p.val()))
}

/// Where a dot's narrow band goes: centre, radius and edge sigma.
#[derive(Clone, Copy, Debug)]
struct Start {
    c: [f64; 2],
    r: f64,
    sig: f64,
}

impl Start {
    /// The narrow band: ±(2 sigma + margin) about the radius.
    fn band<T: Px>(&self, v: View<T>, p: &Prep, il: &Illum) -> Option<Band> {
        let h = (BAND_SIGMAS * self.sig + BAND_MARGIN).max(1.5);
        let r_out = (self.r + h).min((0.5 * p.nn).max(self.r + 1.5));
        Band::new(v, self.c, self.r - h, r_out, il)
    }
}

/// One centroid pass at centre `c`, accumulated row by row: weights are exactly 1
/// inside `r_in`, exactly 0 outside `r_out`, and measured in between.
///
/// Speed: the weight `w = (I - B)(1 - t)/d0` (B, t linear in position) is never formed
/// per pixel. Per pixel only exact integer sums Σv, Σv·k, Σv·k² (and Σv² when `SQ`)
/// are taken (`run_sums`); per run they become the dot's intensity moments
/// (Σv, ΣvX, ΣvY, ΣvX², ΣvXY, ΣvY²), per row the band's pixel moments are added in
/// closed form, and the illumination algebra is done once per dot in
/// `Band::finish`. Only the t² term of the weight is dropped: it is symmetric about
/// the window centre, so it moves the centre by < 1e-5 px.
#[derive(Clone, Copy, Debug)]
struct Band {
    cx: f64,
    cy: f64,
    /// Reference pixel for X, Y (nearest the centre).
    qx: i64,
    qy: i64,
    ri2: f64,
    ro2: f64,
    /// Background at q, its slope per unit t, relative gradient, contrast at q.
    b0: f64,
    bl: f64,
    g: [f64; 2],
    d0: f64,
    /// Intensity moments over the band (X = x - qx, Y = y - qy).
    v: [f64; 7],
    /// Pixel moments of the band: N, ΣX, ΣY, ΣX², ΣXY, ΣY².
    m: [f64; 6],
    n_int: f64,
    sx_int: f64,
    sy_int: f64,
}

/// Σ_{k=a}^{b} k^m for m = 0, 1, 2 (b >= a).
#[inline(always)]
fn power_sums(a: f64, b: f64) -> [f64; 3] {
    let s1 = |m: f64| 0.5 * m * (m + 1.0);
    let s2 = |m: f64| m * (m + 1.0) * (2.0 * m + 1.0) * (1.0 / 6.0);
    [b - a + 1.0, s1(b) - s1(a - 1.0), s2(b) - s2(a - 1.0)]
}

impl Band {
    /// None if the window leaves the frame (the dot is cut by the border).
    fn new<T: Px>(v: View<T>, c: [f64; 2], r_in: f64, r_out: f64, il: &Illum) -> Option<Band> {
        let (cx, cy) = (c[0], c[1]);
        if fceil(cx - r_out) < 0
            || fceil(cy - r_out) < 0
            || ffloor(cx + r_out) > v.w as i64 - 1
            || ffloor(cy + r_out) > v.h as i64 - 1
        {
            return None;
        }
        // Re-reference the illumination model from the blob's pixel to q.
        let (qx, qy) = (cx.round() as i64, cy.round() as i64);
        let tq = il.g[0] * (qx - il.px) as f64 + il.g[1] * (qy - il.py) as f64;
        Some(Band {
            cx,
            cy,
            qx,
            qy,
            ri2: if r_in > 0.0 { r_in * r_in } else { 0.0 },
            ro2: r_out * r_out,
            b0: il.b0 + il.bl * tq,
            bl: il.bl * (1.0 + tq),
            g: [il.g[0] / (1.0 + tq), il.g[1] / (1.0 + tq)],
            d0: il.d0 * (1.0 + tq),
            v: [0.0; 7],
            m: [0.0; 6],
            n_int: 0.0,
            sx_int: 0.0,
            sy_int: 0.0,
        })
    }

    /// First and last row of the window.
    fn rows(&self) -> (i64, i64) {
        let r = self.ro2.sqrt();
        (fceil(self.cy - r), ffloor(self.cy + r))
    }

    #[inline]
    fn add_row<T: Px, const SQ: bool>(&mut self, row: &[T], y: i64) {
        let (cx, cy) = (self.cx, self.cy);
        let dy = y as f64 - cy;
        if dy * dy > self.ro2 {
            return;
        }
        let xo = (self.ro2 - dy * dy).sqrt();
        let xa = fceil(cx - xo);
        let xb = ffloor(cx + xo);
        // Row sums: [Σv, ΣvX, ΣvX², Σv²] and pixel sums [n, ΣX, ΣX²].
        let mut rv = [0.0; 4];
        let mut rm = [0.0; 3];
        let mut run = |a: i64, b: i64| {
            if b < a || a < 0 || b as usize >= row.len() {
                return;
            }
            let [s0, s1, s2, s3] = run_sums::<T, true, SQ>(&row[a as usize..=b as usize]);
            let xa = (a - self.qx) as f64;
            rv[0] += s0;
            rv[1] += xa * s0 + s1;
            rv[2] += xa * xa * s0 + 2.0 * xa * s1 + s2;
            rv[3] += s3;
            let ps = power_sums(xa, (b - self.qx) as f64);
            rm[0] += ps[0];
            rm[1] += ps[1];
            rm[2] += ps[2];
        };
        let mut interior = None;
        if dy * dy < self.ri2 {
            let xi = (self.ri2 - dy * dy).sqrt();
            let ia = ffloor(cx - xi) + 1;
            let ib = fceil(cx + xi) - 1;
            if ib >= ia {
                interior = Some((ia, ib));
            }
        }
        match interior {
            Some((ia, ib)) => {
                run(xa, ia - 1);
                run(ib + 1, xb);
                let m = (ib - ia + 1) as f64;
                self.n_int += m;
                self.sx_int += m * (0.5 * (ia + ib) as f64 - cx);
                self.sy_int += m * dy;
            }
            None => run(xa, xb),
        }
        let yy = (y - self.qy) as f64;
        let v = &mut self.v;
        v[0] += rv[0];
        v[1] += rv[1];
        v[2] += yy * rv[0];
        v[3] += rv[2];
        v[4] += yy * rv[1];
        v[5] += yy * yy * rv[0];
        v[6] += rv[3];
        let m = &mut self.m;
        m[0] += rm[0];
        m[1] += rm[1];
        m[2] += yy * rm[0];
        m[3] += rm[2];
        m[4] += yy * rm[1];
        m[5] += yy * yy * rm[0];
    }

    /// The pass result; `step` = the row step used.
    fn finish(&self, step: usize) -> Option<PassOut> {
        let ([v0, vx, vy, vxx, vxy, vyy, v2], [n, mx, my, mxx, mxy, myy]) = (self.v, self.m);
        let (gx, gy) = (self.g[0], self.g[1]);
        let (b0, bl) = (self.b0, self.bl);
        // w d0 = (v - B)(1 - t) ≈ v - v t - b0 + o t, with t = gx X + gy Y and o = b0 - bl
        // the black level; Σ w, Σ w X, Σ w Y over the band:
        let o = b0 - bl;
        let sw = (v0 - (gx * vx + gy * vy) - b0 * n + o * (gx * mx + gy * my)) / self.d0;
        let swx = (vx - (gx * vxx + gy * vxy) - b0 * mx + o * (gx * mxx + gy * mxy)) / self.d0;
        let swy = (vy - (gx * vxy + gy * vyy) - b0 * my + o * (gx * mxy + gy * myy)) / self.d0;
        // About the window centre.
        let (xc, yc) = (self.cx - self.qx as f64, self.cy - self.qy as f64);
        let (swx, swy) = (swx - xc * sw, swy - yc * sw);
        let mass = self.n_int + sw;
        if !(mass > 0.0) {
            return None;
        }
        // Σ w² ≈ Σ (v - B)² / d0² (the (1 - t)² factor is within 2 % of 1).
        let sum_vb = b0 * v0 + bl * (gx * vx + gy * vy);
        let sum_bb = b0 * b0 * n
            + 2.0 * b0 * bl * (gx * mx + gy * my)
            + bl * bl * (gx * gx * mxx + 2.0 * gx * gy * mxy + gy * gy * myy);
        let sww = (v2 - 2.0 * sum_vb + sum_bb) / (self.d0 * self.d0);
        let st = step as f64;
        Some(PassOut {
            c: [
                self.cx + (self.sx_int + swx) / mass,
                self.cy + (self.sy_int + swy) / mass,
            ],
            area: mass * st,
            w1w: (sw - sww) * st,
            n_edge: n * st,
        })
    }
}

/// One centroid pass over every `step`-th row of one dot (see `Band`).
fn centroid_pass<T: Px, const SQ: bool>(
    v: View<T>,
    c: [f64; 2],
    r_in: f64,
    r_out: f64,
    step: usize,
    il: &Illum,
) -> Option<PassOut> {
    let mut b = Band::new(v, c, r_in, r_out, il)?;
    let (y0, y1) = b.rows();
    for y in (y0..=y1).step_by(step) {
        b.add_row::<T, SQ>(v.row(y as usize), y);
    }
    b.finish(step)
}

/// Edge sigma from the partial-coverage mass of a blurred circle of radius `r`:
/// `Σ w(1-w) = 2 π r σ / √π` for a Gaussian edge; noise variance `var_w` per pixel
/// lowers the sum by `n var_w`, added back.
fn edge_sigma(p: &PassOut, var_w: f64) -> f64 {
    let r = (p.area / std::f64::consts::PI).sqrt().max(0.5);
    let m = (p.w1w + p.n_edge * var_w).max(0.0);
    m * std::f64::consts::PI.sqrt() / (2.0 * std::f64::consts::PI * r)
}

/// Half-width of the measured edge band in edge sigmas, plus a margin for the centre
/// uncertainty left after the quick pass (~0.1 px).
///
/// Why this narrow: outside the band the weights are replaced by their exact values
/// (0 or 1), so every band pixel adds noise and only those near the edge add
/// information. The masks are symmetric about the window centre, so truncating the
/// Gaussian tails adds no bias at the fixed point; what remains is the aliasing of the
/// point-sampled mask boundary, which times the tail mass stays below 0.001 px at
/// 2 sigma (measured: 1.5 sigma gives 0.0016 px RMS on noise-free frames and a common
/// 0.0013 px shift when all dots share one sub-pixel phase, 1 sigma 0.008 px). Going
/// from 3 sigma + 1.5 px to 2 sigma + 0.5 px cut the centre noise by 20 % (4 grey
/// levels, blur 1.5 px: 0.012 -> 0.0095 px RMS).
const BAND_SIGMAS: f64 = 2.0;
const BAND_MARGIN: f64 = 0.5;

/// A full pass that moves the centre by more than this (px) had its band misplaced by a
/// good part of the margin: repeat it at the new centre.
const MAX_FINAL_SHIFT: f64 = 0.25;

/// Edge width of the frame (Gaussian sigma, px), measured with a wide centroid pass on
/// the dots nearest 9 points spread over the frame (centre, edges, corners at 80 %).
///
/// The optics blur all dots about alike, so measuring the blur on a few dots and using
/// a narrow band on the rest costs much less than a wide pass on every dot. The upper
/// quartile is used, not the median, so that a blur growing towards one side of the
/// field (a tilted board) still gets a wide enough band everywhere: a band too narrow
/// for a dot's edge biases it, one too wide only adds a little noise.
fn frame_edge_sigma<T: Px>(v: View<T>, cands: &[(&Prep, Illum)]) -> Option<f64> {
    let mut picked: Vec<usize> = Vec::with_capacity(9);
    for fy in [0.2, 0.5, 0.8] {
        for fx in [0.2, 0.5, 0.8] {
            let at = [fx * v.w as f64, fy * v.h as f64];
            let d2 =
                |k: usize| (cands[k].0.c0[0] - at[0]).powi(2) + (cands[k].0.c0[1] - at[1]).powi(2);
            if let Some(k) = (0..cands.len()).min_by(|&a, &b| d2(a).total_cmp(&d2(b))) {
                if !picked.contains(&k) {
                    picked.push(k);
                }
            }
        }
    }
    let mut sig: Vec<f64> = picked
        .iter()
        .filter_map(|&k| wide_pass(v, cands[k].0, &cands[k].1).map(|q| q.1))
        .collect();
    if sig.is_empty() {
        return None;
    }
    sig.sort_by(|a, b| a.total_cmp(b));
    Some(sig[(3 * (sig.len() - 1)).div_ceil(4)])
}

/// The wide first pass: centre the window from the coarse estimate (every second row,
/// band wide enough for the coarse error and any blur), measuring radius and edge
/// width. Returns (centre, edge sigma, radius).
fn wide_pass<T: Px>(v: View<T>, p: &Prep, il: &Illum) -> Option<([f64; 2], f64, f64)> {
    let var_w = (p.ring.sigma / il.d0).powi(2);
    let m1 = p.h0 + p.e0;
    let half = (0.5 * p.nn).max(p.r0 + 1.0);
    let q1 = centroid_pass::<T, true>(v, p.c0, p.r0 - m1, (p.r0 + m1).min(half), 2, il)?;
    let r1 = (q1.area / std::f64::consts::PI).sqrt();
    Some((q1.c, edge_sigma(&q1, var_w), r1))
}

/// Centre and radius from two horizontal chords, at half a radius above and below the
/// coarse centre: the midpoint of a horizontal chord of a circle is its centre x, and
/// the two half-lengths a1, a2 at rows y1, y2 give the centre y from
/// a1² + (y1 - cy)² = a2² + (y2 - cy)² = r². Each chord end is where the weight
/// crosses 0.5, interpolated between pixels. About 50 pixel reads on 2 rows (rows, not
/// columns, so that they are cheap to fetch), good to ~0.1 px: enough to place the
/// narrow band. None when a chord is not found cleanly (dirt, a tiny or cut dot).
fn chord_start<T: Px>(v: View<T>, p: &Prep, il: &Illum) -> Option<([f64; 2], f64)> {
    let w = v.w as i64;
    let x0 = p.c0[0].round() as i64;
    let off = (0.5 * p.r0).round().max(1.0) as i64;
    // A point certainly inside the chord, and how far the edge can be from it.
    let half_chord = (p.r0 * p.r0 - (off as f64 + p.e0).powi(2)).max(0.0).sqrt();
    let inside = (half_chord - p.h0 - p.e0 - 1.0).max(0.0) as i64;
    let reach = (p.r0 - inside as f64 + p.h0 + p.e0 + 4.0) as i64;
    let weight = |row: &[T], x: i64, y: i64| -> f64 {
        let t = il.g[0] * (x - il.px) as f64 + il.g[1] * (y - il.py) as f64;
        (row[x as usize].val() as f64 - il.b0 - il.bl * t) * (1.0 - t) / il.d0
    };
    // Walk from x along the row in direction dx until the weight drops below 0.5.
    let edge = |row: &[T], y: i64, x: i64, dx: i64| -> Option<f64> {
        let mut prev = weight(row, x, y);
        if prev <= 0.5 {
            return None;
        }
        for step in 1..=reach {
            let nx = x + dx * step;
            if nx < 0 || nx >= w {
                return None;
            }
            let cur = weight(row, nx, y);
            if cur < 0.5 {
                let f = (prev - 0.5) / (prev - cur);
                return Some((nx - dx) as f64 + dx as f64 * f);
            }
            prev = cur;
        }
        None
    };
    let y0 = p.c0[1].round() as i64;
    let (ya, yb) = (y0 - off, y0 + off);
    if ya < 0 || yb >= v.h as i64 || x0 - inside < 0 || x0 + inside >= w {
        return None;
    }
    let chord = |y: i64| -> Option<(f64, f64)> {
        let row = v.row(y as usize);
        let l = edge(row, y, x0 - inside, -1)?;
        let r = edge(row, y, x0 + inside, 1)?;
        Some((0.5 * (l + r), 0.5 * (r - l)))
    };
    let (ma, ha) = chord(ya)?;
    let (mb, hb) = chord(yb)?;
    let (yaf, ybf) = (ya as f64, yb as f64);
    let cy = (ha * ha - hb * hb + yaf * yaf - ybf * ybf) / (2.0 * (yaf - ybf));
    let c = [0.5 * (ma + mb), cy];
    let r = (0.5 * (ha * ha + (yaf - cy).powi(2) + hb * hb + (ybf - cy).powi(2))).sqrt();
    // Chords of one circle share their midpoint; if not, something is in the way.
    let moved = (c[0] - p.c0[0]).hypot(c[1] - p.c0[1]);
    ((ma - mb).abs() < 0.5 && moved <= p.e0 + 1.0 && (r / p.r0 - 1.0).abs() < 0.3).then_some((c, r))
}

/// Check a dot's first narrow pass (taken without the edge-width sums); if it moved
/// the centre by more than the band margin allows, repeat it alone around the new
/// centre, measuring the dot's own edge width (a dot blurrier than the frame gets a
/// band to match).
fn finish_dot<T: Px>(v: View<T>, p: &Prep, il: &Illum, st: Start, first: PassOut) -> Option<Dot> {
    let var_w = (p.ring.sigma / il.d0).powi(2);
    let (mut c, mut sig) = (st.c, st.sig);
    let mut q = first;
    let mut moved = (q.c[0] - c[0]).hypot(q.c[1] - c[1]);
    let mut tries = 0;
    while moved > MAX_FINAL_SHIFT && tries < 3 {
        c = q.c;
        let r = (q.area / std::f64::consts::PI).sqrt();
        let mut b = Start { c, r, sig }.band(v, p, il)?;
        let (y0, y1) = b.rows();
        for y in y0..=y1 {
            b.add_row::<T, true>(v.row(y as usize), y);
        }
        q = b.finish(1)?;
        moved = (q.c[0] - c[0]).hypot(q.c[1] - c[1]);
        // The band (±2 sigma) holds ~97 % of the partial-coverage mass.
        let sig_dot = edge_sigma(&q, var_w) / 0.97;
        if sig_dot > 1.3 * sig {
            sig = sig_dot;
            moved = f64::INFINITY;
        }
        tries += 1;
    }
    let shift = (q.c[0] - p.c0[0]).hypot(q.c[1] - p.c0[1]);
    if moved > MAX_FINAL_SHIFT || shift > p.e0 + 2.0 + 0.1 * p.r0 {
        return None;
    }
    Some(Dot {
        x: q.c[0],
        y: q.c[1],
        area_px: q.area,
        edge_sigma_px: sig,
        contrast: il.d0,
        noise: p.ring.sigma,
    })
}
