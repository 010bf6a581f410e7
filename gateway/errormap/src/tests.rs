use super::*;
use protocol::errormap::{Grid, Identity, Line, Measured, Node, Stat, SCHEMA};

fn stat(mean: f64) -> Stat {
    Stat {
        mean,
        sd: 0.0,
        n: 1,
    }
}

fn measured(ex: f64, ey: f64, yaw: f64) -> Measured {
    Measured {
        ex_um: stat(ex),
        ey_um: stat(ey),
        yaw_urad: stat(yaw),
    }
}

/// A map whose nodes hold `f(x, y, forward)` = (ex, ey, yaw).
fn map_of(xs: Vec<f64>, ys: Vec<f64>, f: impl Fn(f64, f64, bool) -> (f64, f64, f64)) -> ErrorMap {
    let node = |x, y| {
        let (a, b, c) = f(x, y, true);
        let (d, e, g) = f(x, y, false);
        Node {
            forward: measured(a, b, c),
            reverse: measured(d, e, g),
        }
    };
    let nodes = ys
        .iter()
        .flat_map(|&y| xs.iter().map(move |&x| (x, y)))
        .map(|(x, y)| node(x, y))
        .collect();
    ErrorMap {
        schema: SCHEMA.into(),
        version: 1,
        created: "2026-11-22T00:00:00Z".into(),
        identity: Identity {
            machine: "m".into(),
            controller: "c".into(),
            board: "b".into(),
            certificate_sha256: String::new(),
            camera: "cam".into(),
        },
        tool_offset_mm: [0.0, 0.0],
        board_at_machine_zero_mm: [0.0, 0.0],
        reference_mm: [0.0, 0.0],
        grid: Grid { xs, ys, nodes },
        x_lines: Vec::new(),
        y_lines: Vec::new(),
        uncertainty_um: 0.0,
    }
}

fn steps(from: f64, to: f64, step: f64) -> Vec<f64> {
    let n = ((to - from) / step).round() as usize;
    (0..=n)
        .map(|k| from + (to - from) * k as f64 / n as f64)
        .collect()
}

#[test]
fn hermite_is_exact_on_lines_and_smooth_at_nodes() {
    let xs = [0.0, 1.0, 3.0, 4.0];
    let line = |x: f64| 2.0 * x - 1.0;
    for x in [0.0, 0.5, 1.0, 2.2, 3.9, 4.0] {
        assert!((hermite(&xs, |i| line(xs[i]), x) - line(x)).abs() < 1e-12);
    }
    // C1 at an inner node: slopes from both sides agree.
    let f = |i: usize| [0.0, 1.0, 0.0, 2.0][i];
    let h = 1e-7;
    let left = (hermite(&xs, f, 1.0) - hermite(&xs, f, 1.0 - h)) / h;
    let right = (hermite(&xs, f, 1.0 + h) - hermite(&xs, f, 1.0)) / h;
    assert!((left - right).abs() < 1e-4, "{left} {right}");
}

#[test]
fn direction_selects_each_axis_own_measurements() {
    // Forward: ex = 10, ey = -5; reverse: ex = 18, ey = -11 (8 and 6 um of backlash).
    let m = MapModel::new(map_of(vec![0.0, 100.0], vec![0.0, 50.0], |_, _, fwd| {
        if fwd {
            (10.0, -5.0, 0.0)
        } else {
            (18.0, -11.0, 0.0)
        }
    }));
    let p = [40.0, 20.0];
    let close = |a: [f64; 2], b: [f64; 2]| (a[0] - b[0]).abs() < 1e-9 && (a[1] - b[1]).abs() < 1e-9;
    let forward = m.camera_error_um(p, Direction::FORWARD).unwrap();
    assert!(close(forward, [10.0, -5.0]), "{forward:?}");
    let mixed = Direction {
        x: Approach::Reverse,
        y: Approach::Forward,
    };
    let got = m.camera_error_um(p, mixed).unwrap();
    assert!(close(got, [18.0, -5.0]), "{got:?}");
    assert_eq!(
        Direction::of_move([5.0, 5.0], [4.0, 5.0], Direction::FORWARD),
        mixed
    );
}

#[test]
fn the_inverse_puts_the_tool_on_the_nominal_point_and_abbe_follows_the_yaw() {
    let m = map_of(
        steps(0.0, 200.0, 20.0),
        steps(0.0, 150.0, 25.0),
        |x, y, _| {
            (
                0.1 * x + 3.0 * (x / 30.0).sin(),
                -0.05 * y + 0.02 * x,
                0.05 * x, // urad
            )
        },
    );
    let mut m = m;
    m.tool_offset_mm = [30.0, 0.0];
    let model = MapModel::new(m);
    // The worked example of the docs: yaw +10 urad (at x = 200, against 0 at the
    // reference) on a (30, 0) mm offset adds 0.30 um in +Y.
    let cam = model
        .camera_error_um([200.0, 0.0], Direction::FORWARD)
        .unwrap();
    let tool = model
        .tool_error_um([200.0, 0.0], Direction::FORWARD)
        .unwrap();
    assert!((tool[1] - cam[1] - 0.30).abs() < 1e-9, "{cam:?} {tool:?}");
    for p in [[37.3, 81.2], [199.0, 149.0], [0.5, 0.5]] {
        let c = model.command_for(p, Direction::FORWARD).unwrap();
        let e = model.tool_error_um(c, Direction::FORWARD).unwrap();
        let landed = [c[0] + e[0] / 1000.0, c[1] + e[1] / 1000.0];
        assert!(
            (landed[0] - p[0]).abs() < 1e-6 && (landed[1] - p[1]).abs() < 1e-6,
            "{p:?} -> {c:?} lands at {landed:?}"
        );
    }
}

#[test]
fn points_outside_the_map_are_refused_never_extrapolated() {
    let m = MapModel::new(map_of(vec![0.0, 100.0], vec![0.0, 50.0], |_, _, _| {
        (0.0, 0.0, 0.0)
    }));
    let e = m
        .camera_error_um([100.5, 10.0], Direction::FORWARD)
        .unwrap_err();
    assert!(e.to_string().contains("outside the map"), "{e}");
    assert!(m.command_for([-1.0, 10.0], Direction::FORWARD).is_err());
}

#[test]
fn dense_lines_add_the_short_period_error_the_grid_cannot_hold() {
    // A 5 mm period pitch error along X on top of a smooth trend; the grid (every
    // 20 mm) sees only the trend's samples, the line (every 1 mm) the period.
    let truth = |x: f64| 0.05 * x + 2.0 * (2.0 * std::f64::consts::PI * x / 5.0).sin();
    let mut map = map_of(
        steps(0.0, 200.0, 20.0),
        steps(0.0, 150.0, 25.0),
        |x, _, _| (truth(x), 0.0, 0.0),
    );
    let on_grid_only = MapModel::new(map.clone());
    let positions = steps(0.0, 200.0, 1.0);
    let nodes = positions
        .iter()
        .map(|&x| Node {
            forward: measured(truth(x), 0.0, 0.0),
            reverse: measured(truth(x), 0.0, 0.0),
        })
        .collect();
    map.x_lines.push(Line {
        at_mm: 75.0,
        positions,
        nodes,
    });
    let with_line = MapModel::new(map);
    let worst = |m: &MapModel| {
        (0..2000)
            .map(|k| {
                let p = [k as f64 * 0.0999, 33.0 + (k % 7) as f64 * 15.0];
                (m.camera_error_um(p, Direction::FORWARD).unwrap()[0] - truth(p[0])).abs()
            })
            .fold(0.0, f64::max)
    };
    assert!(
        worst(&on_grid_only) > 1.5,
        "the grid alone misses the period"
    );
    let w = worst(&with_line);
    assert!(w < 0.15, "with the dense line: {w} um");
}

/// The model against the simulated C5 stage it is built from (no camera: the truth at
/// each node stands for a perfect measurement): a 21 x 16 grid and one dense line per
/// axis predict where the camera is at random points approached from random sides.
#[test]
fn a_map_of_the_simulated_stage_predicts_it_at_random_points() {
    use protocol::config::ConfigDoc;
    use std::path::Path;
    use world::machine::{MachineConfig, SimMachine};
    let text = include_str!("../../../config/machines/c5-stage.toml");
    let mut cfg =
        MachineConfig::from_doc(&ConfigDoc::from_text("c5-stage.toml", text, Path::new(".")))
            .unwrap();
    // Time-independent: thermal drift is what re-referencing and spot checks are for.
    cfg.thermal = None;
    let camera = world::camera::CameraModel::from_doc(&ConfigDoc::from_text(
        "cam.toml",
        include_str!("../../../config/cameras/mono-1.3mp.toml"),
        Path::new("."),
    ))
    .unwrap();
    let board = protocol::Board::nominal(
        "b",
        0.5,
        0.25,
        protocol::Polarity::DarkOnLight,
        420,
        320,
        [0.0, 0.0],
    );
    let zero = cfg.machine.board_at_home_mm;
    let mut rig = world::rig::SimRig::new(SimMachine::new(cfg), board, camera);
    rig.machine_mut().home();
    let approach = 0.05;
    // Move onto `p` from the side `dir` says; the camera's error there, and its yaw.
    let mut visit = |p: [f64; 2], dir: Direction| {
        let side = |a: Approach| match a {
            Approach::Forward => -approach,
            Approach::Reverse => approach,
        };
        let from = [
            (p[0] + side(dir.x)).clamp(0.0, 200.0),
            (p[1] + side(dir.y)).clamp(0.0, 150.0),
        ];
        for q in [from, p] {
            rig.machine_mut().start_move(q, 3000.0).unwrap();
            rig.machine_mut().finish_motion();
        }
        let pose = rig.truth();
        (
            [
                (pose.centre_mm[0] - p[0] - zero[0]) * 1000.0,
                (pose.centre_mm[1] - p[1] - zero[1]) * 1000.0,
            ],
            pose.rotation_rad * 1e6,
        )
    };
    let mut node_at = |x: f64, y: f64| {
        let (f, yf) = visit([x, y], Direction::FORWARD);
        let (r, yr) = visit([x, y], Direction::REVERSE);
        Node {
            forward: measured(f[0], f[1], yf),
            reverse: measured(r[0], r[1], yr),
        }
    };
    let (xs, ys) = (steps(0.0, 200.0, 10.0), steps(0.0, 150.0, 10.0));
    let nodes: Vec<Node> = ys
        .iter()
        .flat_map(|&y| xs.iter().map(move |&x| (x, y)))
        .map(|(x, y)| node_at(x, y))
        .collect();
    let xline = steps(0.0, 200.0, 1.0);
    let yline = steps(0.0, 150.0, 1.0);
    let x_nodes = xline.iter().map(|&x| node_at(x, 75.0)).collect();
    let y_nodes = yline.iter().map(|&y| node_at(100.0, y)).collect();
    let mut map = map_of(vec![0.0, 1.0], vec![0.0, 1.0], |_, _, _| (0.0, 0.0, 0.0));
    map.grid = Grid { xs, ys, nodes };
    map.x_lines = vec![Line {
        at_mm: 75.0,
        positions: xline,
        nodes: x_nodes,
    }];
    map.y_lines = vec![Line {
        at_mm: 100.0,
        positions: yline,
        nodes: y_nodes,
    }];
    map.check().unwrap();
    let model = MapModel::new(map);
    // 1000 random points, random approach sides (a fixed xorshift sequence).
    let mut s = 0x9E37_79B9_7F4A_7C15u64;
    let mut next = || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let (mut worst, mut sum2, mut raw_worst) = (0.0f64, 0.0, 0.0f64);
    let n = 1000;
    for _ in 0..n {
        let p = [1.0 + 198.0 * next(), 1.0 + 148.0 * next()];
        let side = |u: f64| {
            if u < 0.5 {
                Approach::Forward
            } else {
                Approach::Reverse
            }
        };
        let dir = Direction {
            x: side(next()),
            y: side(next()),
        };
        let (truth, _) = visit(p, dir);
        let e = model.camera_error_um(p, dir).unwrap();
        let miss = (truth[0] - e[0]).hypot(truth[1] - e[1]);
        worst = worst.max(miss);
        raw_worst = raw_worst.max(truth[0].hypot(truth[1]));
        sum2 += miss * miss;
    }
    let rms = (sum2 / n as f64).sqrt();
    assert!(
        raw_worst > 15.0,
        "an ordinary stage: {raw_worst} um uncompensated"
    );
    assert!(
        worst <= 1.5 && rms <= 0.5,
        "map vs truth: max {worst:.3} um, rms {rms:.3} um"
    );
}

mod export_tables {
    use super::*;
    use crate::export::*;

    /// X error 0.1 um per mm going up, 8 um less going down; Y error `sq` um per mm of X
    /// (X's straightness seen in Y) and none of its own.
    fn linear(sq: f64) -> MapModel {
        MapModel::new(map_of(
            steps(0.0, 100.0, 10.0),
            steps(0.0, 50.0, 10.0),
            move |x, _, fwd| (0.1 * x - if fwd { 0.0 } else { 8.0 }, sq * x, 0.0),
        ))
    }

    #[test]
    fn linuxcnc_lines_are_nominal_forward_reverse_actual_positions() {
        let t = linuxcnc_joint(&linear(0.0), 0, 11, 0.5).unwrap();
        let lines: Vec<&str> = t.text.lines().collect();
        assert_eq!(lines.len(), 11);
        // No header, no comment, no commas: three numbers on every line (anything else
        // makes LinuxCNC load nothing, silently).
        for l in &lines {
            let w: Vec<&str> = l.split(' ').collect();
            assert_eq!(w.len(), 3, "{l:?}");
            assert!(w.iter().all(|v| v.parse::<f64>().is_ok()), "{l:?}");
        }
        // At 50 mm: 5 um further going up, 3 um short going down.
        assert_eq!(lines[5], "50.000000 50.005000 49.997000");
        assert!(
            t.interpolation_error_um < 1e-6,
            "{}",
            t.interpolation_error_um
        );
        assert!(t.cross_terms_um < 1e-6);
    }

    #[test]
    fn linuxcnc_says_what_it_cannot_hold() {
        // Y's error grows with X (0.05 um/mm): the Y joint's table, a function of Y only,
        // loses up to 5 um over 100 mm of X.
        let t = linuxcnc_joint(&linear(0.05), 1, 6, 0.5).unwrap();
        assert!(
            (t.cross_terms_um - 5.0).abs() < 1e-6,
            "{}",
            t.cross_terms_um
        );
    }

    #[test]
    fn linuxcnc_refuses_more_than_256_entries_and_a_table_too_coarse() {
        assert!(matches!(
            linuxcnc_joint(&linear(0.0), 0, 257, 0.5),
            Err(ExportError::Options(_))
        ));
        // A 5 mm-period screw error of 3 um over 500 mm: 256 entries are 1.96 mm apart,
        // far too coarse for a 5 mm period at 0.5 um.
        let k = std::f64::consts::TAU / 5.0;
        let screw = MapModel::new(map_of(
            steps(0.0, 500.0, 0.5),
            vec![0.0, 10.0],
            move |x, _, _| (3.0 * (k * x).sin(), 0.0, 0.0),
        ));
        let e = linuxcnc_joint(&screw, 0, 256, 0.5).unwrap_err();
        assert!(matches!(e, ExportError::BeyondTolerance { .. }), "{e}");
        assert!(e.to_string().contains("at most 256"), "{e}");
    }

    #[test]
    fn linuxcnc_refuses_nominals_that_would_not_increase_as_written() {
        // 0.0002 mm of X in 256 entries: 6 decimals write several entries alike.
        let tiny = MapModel::new(map_of(
            vec![0.0, 0.0002],
            vec![0.0, 10.0],
            move |_, _, _| (0.0, 0.0, 0.0),
        ));
        let e = linuxcnc_joint(&tiny, 0, 256, 0.5).unwrap_err();
        assert!(matches!(e, ExportError::Options(_)), "{e}");
        assert!(e.to_string().contains("strictly increasing"), "{e}");
        // Three entries over the same 0.0002 mm are written apart.
        assert!(linuxcnc_joint(&tiny, 0, 3, 0.5).is_ok());
    }

    #[test]
    fn beckhoff_corrections_are_minus_the_mean_error_in_tenths_of_a_micrometre() {
        let m = MapModel::new(map_of(
            steps(0.0, 100.0, 10.0),
            steps(0.0, 50.0, 10.0),
            |_, _, fwd| (if fwd { 10.0 } else { 6.0 }, -2.5, 0.0),
        ));
        let t = beckhoff_plane(&m, 0, 10.0, 0.5).unwrap();
        assert!(
            t.text
                .contains("kw.crosscomp2.table[  0][   0].correction -80"),
            "{}",
            t.text
        );
        assert!(t
            .text
            .contains("kw.crosscomp2.interval                     100000"));
        assert!(t
            .text
            .contains("kw.crosscomp2.last_index_master1           10"));
        assert!(t
            .text
            .contains("kw.crosscomp2.last_index_master2           5"));
        assert_eq!(t.points, 66);
        assert!(
            (t.backlash_lost_um - 2.0).abs() < 1e-9,
            "{}",
            t.backlash_lost_um
        );
        let y = beckhoff_plane(&m, 1, 10.0, 0.5).unwrap();
        assert!(y
            .text
            .contains("kopf.log_achs_name                         Y"));
        assert!(y.text.contains("correction 25"), "{}", y.text);
    }

    #[test]
    fn the_plain_csv_holds_every_node_as_the_model_gives_it() {
        let m = linear(0.05);
        let csv = plain_csv(&m).unwrap();
        let rows: Vec<Vec<f64>> = csv
            .lines()
            .skip(1)
            .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
            .collect();
        assert_eq!(rows.len(), 11 * 6);
        for r in &rows {
            let f = m.camera_error_um([r[0], r[1]], Direction::FORWARD).unwrap();
            let b = m.camera_error_um([r[0], r[1]], Direction::REVERSE).unwrap();
            assert!((r[2] - f[0]).abs() < 1e-4 && (r[3] - f[1]).abs() < 1e-4);
            assert!((r[5] - b[0]).abs() < 1e-4 && (r[6] - b[1]).abs() < 1e-4);
        }
    }
}

/// The heat map says what its colours mean (a scale in µm up to the largest error) and
/// where each node's error points: one arrow per node with an error, none where there
/// is none, and the arrow along the error's direction.
#[test]
fn the_heat_map_has_its_colour_scale_and_an_arrow_per_node() {
    let xs = steps(0.0, 100.0, 50.0);
    let ys = steps(0.0, 50.0, 50.0);
    // +X error growing along X; none at x = 0.
    let map = map_of(xs, ys, |x, _, _| (x / 10.0, 0.0, 0.0));
    let chart = heatmap::HeatMap {
        map: &map,
        title: "test".into(),
    };
    assert_eq!(chart.error_xy_um(2, 1), (10.0, 0.0));
    let svg = plot::render_svg(&chart, 900, 600).unwrap();
    // The colour scale is written at both ends: 0 and the largest error, 10 µm.
    assert!(svg.contains("|e|, µm"), "the scale says its unit");
    for end in ["\n10\n", "\n0\n"] {
        assert!(svg.contains(end), "no {end:?} at an end of the scale");
    }
    // The arrows' scale: 10 µm is 22.5 mm long (45 % of the 50 mm step), so a round
    // length that fits under the colour scale, drawn as the arrows are.
    assert!(
        svg.contains("arrow 5 µm") || svg.contains("arrow 2 µm"),
        "no arrow scale"
    );
    // 4 of the 6 nodes have an error: a shaft and a head each; and the scale's arrow.
    let polylines = svg.matches("stroke=\"#141414\"").count();
    assert_eq!(polylines, 8 + 2, "{polylines} strokes");
}

/// Two scans of the same grid: the change is found node by node, at its place; a map of
/// another camera says so; another grid cannot be compared, and says why.
#[test]
fn two_versions_of_a_map_are_compared_node_by_node() {
    let xs = steps(0.0, 100.0, 50.0);
    let ys = steps(0.0, 50.0, 25.0);
    let old = map_of(xs.clone(), ys.clone(), |x, y, _| (x / 10.0, y / 10.0, 0.0));
    // The same machine with a 3-4-5 um change at (50, 25) only.
    let mut new = map_of(xs.clone(), ys.clone(), |x, y, _| {
        let bump = if x == 50.0 && y == 25.0 {
            (3.0, 4.0)
        } else {
            (0.0, 0.0)
        };
        (x / 10.0 + bump.0, y / 10.0 + bump.1, 0.0)
    });
    let d = diff::compare(&old, &new).unwrap();
    assert_eq!(d.nodes, 9);
    assert!((d.max_um - 5.0).abs() < 1e-12, "{d:?}");
    assert_eq!(d.max_at_mm, [50.0, 25.0]);
    assert_eq!(d.max_change_um, [3.0, 4.0]);
    assert!((d.rms_um - (25.0f64 / 9.0).sqrt()).abs() < 1e-12);
    assert!(d.identity_changed.is_empty());
    new.identity.camera = "another".into();
    assert_eq!(
        diff::compare(&old, &new).unwrap().identity_changed,
        ["camera"]
    );
    let coarser = map_of(xs, steps(0.0, 50.0, 50.0), |_, _, _| (0.0, 0.0, 0.0));
    let e = diff::compare(&old, &coarser).unwrap_err();
    assert!(e.contains("the grids differ"), "{e}");
}

/// Issue 38: the diff read "at most 0.00 um" for a backlash change of 16 um on every
/// node, a yaw of 500 urad and +20 um on every line node, and 2.5 um for one node's
/// forward +5 um. It compares what compensation uses: each is seen, with its own figure.
#[test]
fn the_diff_sees_each_direction_the_lines_the_yaw_the_squareness_and_the_backlash() {
    let xs = steps(0.0, 100.0, 50.0);
    let ys = steps(0.0, 100.0, 50.0);
    let base = |x: f64, y: f64, _| (x / 10.0, y / 10.0, 0.0);
    let old = map_of(xs.clone(), ys.clone(), base);
    let same = diff::compare(&old, &old).unwrap();
    assert_eq!(same.max_um, 0.0);
    assert_eq!(same.squareness_change_urad, 0.0);
    // One node's forward approach only, +5 um in X: 5, not the average of both sides.
    let one = map_of(xs.clone(), ys.clone(), |x, y, forward| {
        let (ex, ey, yaw) = base(x, y, forward);
        let bump = if forward && x == 50.0 && y == 50.0 {
            5.0
        } else {
            0.0
        };
        (ex + bump, ey, yaw)
    });
    let d = diff::compare(&old, &one).unwrap();
    assert!((d.max_um - 5.0).abs() < 1e-9, "{d:?}");
    assert_eq!(d.max_at_mm, [50.0, 50.0]);
    assert!(d.max_approach.starts_with("x forward"), "{d:?}");
    assert!((d.backlash_max_um - 5.0).abs() < 1e-9, "{d:?}");
    // Backlash: the reverse side 16 um further on every node (the mean moves by 8).
    let lash = map_of(xs.clone(), ys.clone(), |x, y, forward| {
        let (ex, ey, yaw) = base(x, y, forward);
        (if forward { ex } else { ex + 16.0 }, ey, yaw)
    });
    let d = diff::compare(&old, &lash).unwrap();
    assert!((d.max_um - 16.0).abs() < 1e-9, "{d:?}");
    assert!((d.backlash_max_um - 16.0).abs() < 1e-9, "{d:?}");
    // A yaw growing to 500 urad at X 100 (the map's yaw is relative to its reference
    // point, here X 0): its own figure, and on a tool 100 mm from the camera it moves
    // the tool by 50 um there.
    let yawed = map_of(xs.clone(), ys.clone(), |x, y, f| {
        let (ex, ey, _) = base(x, y, f);
        (ex, ey, 5.0 * x)
    });
    let d = diff::compare(&old, &yawed).unwrap();
    assert!((d.yaw_max_urad - 500.0).abs() < 1e-9, "{d:?}");
    let (mut armed_old, mut armed_new) = (old.clone(), yawed.clone());
    armed_old.tool_offset_mm = [0.0, 100.0];
    armed_new.tool_offset_mm = [0.0, 100.0];
    let d = diff::compare(&armed_old, &armed_new).unwrap();
    assert!((d.max_um - 50.0).abs() < 0.5, "{d:?}");
    // Squareness: X's error grows by 5 um more over 100 mm of Y: +50 urad.
    let leaning = map_of(xs.clone(), ys.clone(), |x, y, f| {
        let (ex, ey, yaw) = base(x, y, f);
        (ex + 0.05 * y, ey, yaw)
    });
    let d = diff::compare(&old, &leaning).unwrap();
    assert!((d.squareness_change_urad - 50.0).abs() < 1e-9, "{d:?}");
    assert!((d.max_um - 5.0).abs() < 1e-9, "{d:?}");
    // A turned board (ex = -t y, ey = t x) is no squareness.
    let turned = map_of(xs.clone(), ys.clone(), |x, y, f| {
        let (ex, ey, yaw) = base(x, y, f);
        (ex - 0.05 * y, ey + 0.05 * x, yaw)
    });
    assert!(
        diff::compare(&old, &turned)
            .unwrap()
            .squareness_change_urad
            .abs()
            < 1e-9
    );
    // The dense lines: +20 um on every line node, the grid unchanged.
    let line = |ex: f64| Line {
        at_mm: 50.0,
        positions: steps(0.0, 100.0, 1.0),
        nodes: steps(0.0, 100.0, 1.0)
            .iter()
            .map(|&x| Node {
                forward: measured(x / 10.0 + ex, 5.0, 0.0),
                reverse: measured(x / 10.0 + ex, 5.0, 0.0),
            })
            .collect(),
    };
    let (mut lined_old, mut lined_new) = (old.clone(), old.clone());
    lined_old.x_lines.push(line(0.0));
    lined_new.x_lines.push(line(20.0));
    let d = diff::compare(&lined_old, &lined_new).unwrap();
    assert!(d.lines_max_um >= 19.9, "{d:?}");
    assert!(d.max_um >= 19.9, "{d:?}");
    // Grids that differ are named without Rust's `Some(..)`.
    let coarser = map_of(xs, steps(0.0, 100.0, 100.0), base);
    let e = diff::compare(&old, &coarser).unwrap_err();
    assert!(e.contains("Y 0..100") && !e.contains("Some"), "{e}");
}
