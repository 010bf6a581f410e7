//! Two versions of an error map compared as compensation uses them: how far the machine's
//! errors moved between two scans (drift, a crash, a re-levelled table), which the
//! operator reads before activating a new version.
//!
//! Each map's model ([`MapModel`]) is evaluated at every grid node and every sample of
//! its dense lines, from each of the four approaches (X from below or above, Y from
//! below or above), for the tool point (the camera's error plus the yaw acting on the
//! map's tool offset): the figures are how far a compensated command moves. A change of
//! one direction only (backlash), of the dense lines only (a screw's pitch error), of
//! the yaw or of the squareness is seen where it acts. The yaw and the squareness are
//! also reported on their own, since a zero tool offset hides the yaw.
//!
//! Squareness convention: from a least-squares plane through each error over the grid
//! (both approaches averaged), `d(ex)/dy + d(ey)/dx` in urad (um per m): a board turned
//! on the table (`ex = -t y`, `ey = t x`) has none; a Y axis leaning toward +X by 50 urad
//! (`ex = 0.05 um/mm x y`) has +50. Worked example: a new scan whose X error grows by an
//! extra 5 um over 100 mm of Y reports `squareness_change_urad` = +50.

use crate::Approach;
use crate::{Direction, MapModel};
use protocol::errormap::ErrorMap;
use serde::Serialize;

/// The change from `old` to `new`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MapDiff {
    /// Points compared: grid nodes and dense-line samples (each from four approaches).
    pub nodes: usize,
    /// |Δe| of the tool point's in-plane error over the points and approaches, um.
    pub max_um: f64,
    pub rms_um: f64,
    /// Where the largest change is, machine mm, the change there (new - old), um, and
    /// the approach it is for (`forward` = from below, per axis: `x forward, y reverse`).
    pub max_at_mm: [f64; 2],
    pub max_change_um: [f64; 2],
    pub max_approach: String,
    /// The largest change of the dense lines' detail alone, um (0 without lines).
    pub lines_max_um: f64,
    /// The largest change of the yaw over the points and approaches, urad.
    pub yaw_max_urad: f64,
    /// The largest change of the backlash (reverse minus forward error, per axis) at a
    /// grid node, um.
    pub backlash_max_um: f64,
    /// The squareness's change (module documentation), urad.
    pub squareness_change_urad: f64,
    /// The identity fields that differ (`machine`, `camera`, ...): a map of another
    /// machine is not a new version of this one.
    pub identity_changed: Vec<&'static str>,
}

const APPROACHES: [Direction; 4] = [
    Direction::FORWARD,
    Direction {
        x: Approach::Forward,
        y: Approach::Reverse,
    },
    Direction {
        x: Approach::Reverse,
        y: Approach::Forward,
    },
    Direction::REVERSE,
];

fn side(a: Approach) -> &'static str {
    match a {
        Approach::Forward => "forward",
        Approach::Reverse => "reverse",
    }
}

/// `Some(1.5)` as `1.5`, `None` as `none` (for messages).
fn end(v: Option<&f64>) -> String {
    v.map_or("none".into(), |v| format!("{v}"))
}

/// The two maps compared; `Err` names why they cannot be (different grids).
pub fn compare(old: &ErrorMap, new: &ErrorMap) -> Result<MapDiff, String> {
    let (a, b) = (&old.grid, &new.grid);
    if a.xs != b.xs || a.ys != b.ys || a.nodes.len() != b.nodes.len() {
        return Err(format!(
            "the grids differ ({} x {} nodes over X {}..{}, Y {}..{} against {} x {} over X {}..{}, Y {}..{}): compare maps scanned with the same grid",
            a.xs.len(), a.ys.len(), end(a.xs.first()), end(a.xs.last()), end(a.ys.first()), end(a.ys.last()),
            b.xs.len(), b.ys.len(), end(b.xs.first()), end(b.xs.last()), end(b.ys.first()), end(b.ys.last()),
        ));
    }
    let (m0, m1) = (MapModel::new(old.clone()), MapModel::new(new.clone()));
    // Every place compensation reads: the nodes, then both maps' line samples.
    let mut points: Vec<([f64; 2], bool)> = Vec::new();
    for y in &a.ys {
        for x in &a.xs {
            points.push(([*x, *y], false));
        }
    }
    for map in [old, new] {
        for l in &map.x_lines {
            points.extend(l.positions.iter().map(|&s| ([s, l.at_mm], true)));
        }
        for l in &map.y_lines {
            points.extend(l.positions.iter().map(|&s| ([l.at_mm, s], true)));
        }
    }
    let (mut sum2, mut count) = (0.0, 0usize);
    let (mut max, mut at, mut change, mut approach) = (-1.0f64, [0.0; 2], [0.0; 2], String::new());
    let (mut lines_max, mut yaw_max) = (0.0f64, 0.0f64);
    let mut compared = 0;
    for &(p, on_line) in &points {
        compared += usize::from(m0.inside(p).is_ok());
        for dir in APPROACHES {
            let (Ok(e0), Ok(e1)) = (m0.tool_error_um(p, dir), m1.tool_error_um(p, dir)) else {
                continue; // a line sample outside the other map: not comparable there
            };
            let d = [e1[0] - e0[0], e1[1] - e0[1]];
            let m = d[0].hypot(d[1]);
            sum2 += m * m;
            count += 1;
            if m > max {
                (max, at, change) = (m, p, d);
                approach = format!("x {}, y {}", side(dir.x), side(dir.y));
            }
            if on_line {
                lines_max = lines_max.max(m);
            }
            if let (Ok(y0), Ok(y1)) = (m0.yaw_urad(p, dir), m1.yaw_urad(p, dir)) {
                yaw_max = yaw_max.max((y1 - y0).abs());
            }
        }
    }
    let backlash = |n: &protocol::errormap::Node| {
        [
            n.reverse.ex_um.mean - n.forward.ex_um.mean,
            n.reverse.ey_um.mean - n.forward.ey_um.mean,
        ]
    };
    let backlash_max = a.nodes.iter().zip(&b.nodes).fold(0.0f64, |m, (p, q)| {
        let (l0, l1) = (backlash(p), backlash(q));
        m.max((l1[0] - l0[0]).abs()).max((l1[1] - l0[1]).abs())
    });
    let (i, j) = (&old.identity, &new.identity);
    let identity_changed = [
        ("machine", i.machine != j.machine),
        ("controller", i.controller != j.controller),
        ("board", i.board != j.board),
        (
            "certificate_sha256",
            i.certificate_sha256 != j.certificate_sha256,
        ),
        ("camera", i.camera != j.camera),
    ]
    .into_iter()
    .filter_map(|(name, changed)| changed.then_some(name))
    .collect();
    Ok(MapDiff {
        nodes: compared,
        max_um: max.max(0.0),
        rms_um: (sum2 / count.max(1) as f64).sqrt(),
        max_at_mm: at,
        max_change_um: change,
        max_approach: approach,
        lines_max_um: lines_max,
        yaw_max_urad: yaw_max,
        backlash_max_um: backlash_max,
        squareness_change_urad: squareness_urad(new) - squareness_urad(old),
        identity_changed,
    })
}

/// `d(ex)/dy + d(ey)/dx` of least-squares planes through the grid's errors (both
/// approaches averaged), urad; 0 for a grid of one row or column.
pub fn squareness_urad(map: &ErrorMap) -> f64 {
    let g = &map.grid;
    let n = g.nodes.len() as f64;
    if g.xs.len() < 2 || g.ys.len() < 2 {
        return 0.0;
    }
    let mean = |v: &dyn Fn(usize) -> f64| (0..g.nodes.len()).map(v).sum::<f64>() / n;
    let x = |k: usize| g.xs[k % g.xs.len()];
    let y = |k: usize| g.ys[k / g.xs.len()];
    let ex = |k: usize| (g.nodes[k].forward.ex_um.mean + g.nodes[k].reverse.ex_um.mean) / 2.0;
    let ey = |k: usize| (g.nodes[k].forward.ey_um.mean + g.nodes[k].reverse.ey_um.mean) / 2.0;
    // On a full grid x and y are uncorrelated: each slope is a simple regression.
    let slope = |u: &dyn Fn(usize) -> f64, e: &dyn Fn(usize) -> f64| {
        let (mu, me) = (mean(u), mean(e));
        let cov = mean(&|k| (u(k) - mu) * (e(k) - me));
        let var = mean(&|k| (u(k) - mu).powi(2));
        cov / var
    };
    // um per mm is mrad: x 1000 for urad.
    (slope(&y, &ex) + slope(&x, &ey)) * 1000.0
}
