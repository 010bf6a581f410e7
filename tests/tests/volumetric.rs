//! The volumetric pipeline end to end against the emulated machine's truth: simulate a
//! campaign, read its files, identify, write and read the model file, compensate 1000
//! random points of the volume, and compare the tool point's true error before and after
//! (with and without the camera campaign at several heights).

use protocol::volumetric::{parse_instrument, parse_model, write_model, Structure};
use volumetric::identify::{identify, laser_columns, Campaign};
use volumetric::Model;
use world::rng::Rng;
use world::volumetric::{CameraPlan, VolumetricMachine};

fn campaign(files: &[(String, String)]) -> Campaign {
    Campaign::from_files(files).unwrap_or_else(|e| panic!("{e}"))
}

fn norm(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

#[test]
fn compensation_removes_at_least_90_percent_of_the_volumetric_error() {
    for (structure, seed) in [
        (Structure::Xyfz, 1),
        (Structure::Fxyz, 2),
        (Structure::Xfyz, 3),
        (Structure::Xyzf, 4),
    ] {
        for with_camera in [false, true] {
            let machine = VolumetricMachine::new(structure, seed);
            let mut files = machine.campaign(seed + 100);
            if with_camera {
                let plan = CameraPlan::default_for(machine.travel_mm);
                files.push(("camera.csv".into(), machine.camera_campaign(&plan, seed).0));
            }
            let id = identify(structure, &campaign(&files)).unwrap();
            assert!(id.model.file.fit, "{structure}");
            assert_eq!(id.camera.is_some(), with_camera);
            // Through the model file, as the CLI would.
            let model = Model::new(parse_model(&write_model(&id.model.file)).unwrap()).unwrap();
            let mut rng = Rng::new(seed * 7919);
            let (mut before_ss, mut after_ss) = (0.0, 0.0);
            let (mut before_max, mut after_max) = (0.0f64, 0.0f64);
            for _ in 0..1000 {
                let target: [f64; 3] =
                    std::array::from_fn(|a| rng.range(1.0, machine.travel_mm[a] - 1.0));
                let before = norm(machine.true_error(target));
                let command = model.command_for(target).unwrap();
                let real = machine.tool_in_work(command);
                let after = norm(std::array::from_fn(|k| real[k] - target[k]));
                before_ss += before * before;
                after_ss += after * after;
                before_max = before_max.max(before);
                after_max = after_max.max(after);
            }
            let (before_rms, after_rms) = ((before_ss / 1000.0).sqrt(), (after_ss / 1000.0).sqrt());
            eprintln!(
                "{structure} (camera {with_camera}): RMS {:.2} -> {:.3} µm, max {:.2} -> {:.3} µm",
                before_rms * 1e3,
                after_rms * 1e3,
                before_max * 1e3,
                after_max * 1e3
            );
            assert!(
                before_rms > 0.005,
                "{structure}: the machine has errors to remove"
            );
            assert!(
                after_rms <= 0.1 * before_rms,
                "{structure}: {after_rms} of {before_rms}"
            );
            assert!(
                after_max <= 0.1 * before_max,
                "{structure}: {after_max} of {before_max}"
            );
        }
    }
}

#[test]
fn a_campaign_file_with_bad_content_is_refused_with_its_line_and_column() {
    let files = VolumetricMachine::new(Structure::Xyfz, 5).campaign(6);
    let laser_y = &files.iter().find(|f| f.0 == "laser_Y.csv").unwrap().1;
    // Line 7 is run 1's first data row (5 header lines, the column row): NaN in E_XY.
    let bad: String = laser_y
        .lines()
        .enumerate()
        .map(|(i, l)| {
            if i == 6 {
                "1,0,NaN,0,0,0,0\n".to_string()
            } else {
                format!("{l}\n")
            }
        })
        .collect();
    let cols = laser_columns(1);
    let cols: Vec<&str> = cols.iter().map(String::as_str).collect();
    let e = parse_instrument(&bad, &cols).unwrap_err();
    assert_eq!((e.line, e.column), (7, 5), "{e}");
    // The X columns given for Y: missing axis data is named.
    let xcols = laser_columns(0);
    let xcols: Vec<&str> = xcols.iter().map(String::as_str).collect();
    let e = parse_instrument(laser_y, &xcols).unwrap_err();
    assert_eq!(e.line, 6, "{e}");
}
