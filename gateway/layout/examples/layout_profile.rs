//! One partition and resolution of one benchmark layout, once: the target for
//! `valgrind --tool=callgrind`, whose instruction counts compare code before and after
//! on a loaded machine (wall times there are noise). Run with
//! `cargo build --release -p layout --example layout_profile` then
//! `valgrind --tool=callgrind --toggle-collect=layout_profile::run
//! target/release/examples/layout_profile NAME [C] [widen]`:
//! NAME a data/esicup layout (`gardeyn7`) or the start of a generated 10 000-part nest's
//! name (`quads`, `diamonds`, `stars 20 mm`); C the clearance as a fraction of the gap
//! (1 or 0.5, ESICUP layouts only); `widen` for `--widen`.

#[path = "../tests/nests/mod.rs"]
mod nests;

use layout::{partition, resolve, resolve_widening, Params, Partition, PartitionError, Resolution};
use layout_io::Part;

/// What is measured (`--toggle-collect=layout_profile::run` counts only this).
#[inline(never)]
fn run(
    parts: &[Part],
    params: &Params,
    widen: bool,
) -> (Partition, Result<Resolution, PartitionError>) {
    let mut p = partition(parts, params).expect("partition");
    let r = if widen {
        resolve_widening(parts, &mut p, &[])
    } else {
        resolve(parts, &mut p, &[])
    };
    (p, r)
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let name = args.first().expect("a layout name");
    let clearance: f64 = args.get(1).and_then(|c| c.parse().ok()).unwrap_or(1.0);
    let widen = args.iter().any(|a| a == "widen");
    let (parts, params) = match nests::esicup().into_iter().find(|(n, _)| n == name) {
        Some((_, doc)) => {
            let doc = doc.expect("layout");
            let params = nests::esicup_params(&doc, clearance);
            (doc.parts, params)
        }
        None => {
            let case = nests::generated(10_000)
                .into_iter()
                .find(|c| c.name.starts_with(name.as_str()))
                .expect("a data/esicup layout or a generated nest");
            (case.parts, case.params)
        }
    };
    let t = std::time::Instant::now();
    let (p, r) = run(&parts, &params, widen);
    let ms = t.elapsed().as_secs_f64() * 1e3;
    match r {
        Ok(r) => println!(
            "{name}: {} groups, {} found, {} moves, {} widenings, {ms:.1} ms",
            p.groups.len(),
            r.found.len(),
            r.moves.len(),
            r.widenings.len()
        ),
        Err(e) => println!(
            "{name}: {} groups, unresolved ({e:.80}), {ms:.1} ms",
            p.groups.len()
        ),
    }
}
