//! A map applies only to the machine it was measured on: `gateway rewrite --config` and
//! `gateway verify` refuse another machine's map naming what differs, before any motion.

use crate::common;

use common::{gateway, job_file as config, scratch};
use std::path::Path;

#[test]
fn another_machines_map_is_refused_naming_what_differs() {
    let dir = scratch("identity", "rewrite");
    let out = dir.display().to_string();
    let demo = config("demo.toml");
    let o = gateway(&[
        "map",
        "--config",
        &demo,
        "--out",
        &out,
        "--name",
        "m",
        "--grid-step-mm",
        "50",
        "--line-step-mm",
        "25",
        "--passes",
        "1",
        "--json",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let map = dir.join("m.v1.json").display().to_string();
    let program = dir.join("p.nc");
    std::fs::write(&program, "G90 G21\nG0 X20 Y20\nG1 X60 Y40 F1200\n").unwrap();
    let program = program.display().to_string();
    let rewritten = dir.join("out.nc").display().to_string();

    // The machine it was measured on: rewritten.
    let o = gateway(&[
        "rewrite", &program, "--map", &map, "--config", &demo, "--out", &rewritten,
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(Path::new(&rewritten).is_file());

    // The same machine behind a GRBL controller is another controller: refused, and
    // nothing written.
    std::fs::remove_file(&rewritten).unwrap();
    let o = gateway(&[
        "rewrite",
        &program,
        "--map",
        &map,
        "--config",
        &config("grbl-demo.toml"),
        "--out",
        &rewritten,
    ]);
    assert!(!o.status.success());
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        e.contains("the map was measured on machine") && e.contains("refused"),
        "{e}"
    );
    assert!(!Path::new(&rewritten).exists());

    // verify refuses it the same way.
    let o = gateway(&[
        "verify",
        "--config",
        &config("grbl-demo.toml"),
        "--map",
        &map,
    ]);
    assert!(!o.status.success());
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains("the map was measured on machine"), "{e}");
}
