//! Two versions of an error map compared node by node: how far the machine's errors
//! moved between two scans (drift, a crash, a re-levelled table), which the operator
//! reads before activating a new version.

use protocol::errormap::ErrorMap;
use serde::Serialize;

/// The change from `old` to `new` at the grid nodes both maps share.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MapDiff {
    /// Nodes compared.
    pub nodes: usize,
    /// |Δe| over the nodes (the in-plane error, mean of both approaches), um.
    pub max_um: f64,
    pub rms_um: f64,
    /// Where the largest change is, machine mm, and the change there (new - old), um.
    pub max_at_mm: [f64; 2],
    pub max_change_um: [f64; 2],
    /// The identity fields that differ (`machine`, `camera`, ...): a map of another
    /// machine is not a new version of this one.
    pub identity_changed: Vec<&'static str>,
}

/// The two maps compared; `Err` names why they cannot be (different grids).
pub fn compare(old: &ErrorMap, new: &ErrorMap) -> Result<MapDiff, String> {
    let (a, b) = (&old.grid, &new.grid);
    if a.xs != b.xs || a.ys != b.ys || a.nodes.len() != b.nodes.len() {
        return Err(format!(
            "the grids differ ({} x {} nodes over X {:?}..{:?}, Y {:?}..{:?} against {} x {} over X {:?}..{:?}, Y {:?}..{:?}): compare maps scanned with the same grid",
            a.xs.len(), a.ys.len(), a.xs.first(), a.xs.last(), a.ys.first(), a.ys.last(),
            b.xs.len(), b.ys.len(), b.xs.first(), b.xs.last(), b.ys.first(), b.ys.last(),
        ));
    }
    let mean = |n: &protocol::errormap::Node| {
        [
            (n.forward.ex_um.mean + n.reverse.ex_um.mean) / 2.0,
            (n.forward.ey_um.mean + n.reverse.ey_um.mean) / 2.0,
        ]
    };
    let (mut sum2, mut max, mut at, mut change) = (0.0, -1.0, [0.0; 2], [0.0; 2]);
    for (k, (p, q)) in a.nodes.iter().zip(&b.nodes).enumerate() {
        let (e0, e1) = (mean(p), mean(q));
        let d = [e1[0] - e0[0], e1[1] - e0[1]];
        let m = d[0].hypot(d[1]);
        sum2 += m * m;
        if m > max {
            max = m;
            at = [a.xs[k % a.xs.len()], a.ys[k / a.xs.len()]];
            change = d;
        }
    }
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
        nodes: a.nodes.len(),
        max_um: max.max(0.0),
        rms_um: (sum2 / a.nodes.len().max(1) as f64).sqrt(),
        max_at_mm: at,
        max_change_um: change,
        identity_changed,
    })
}
