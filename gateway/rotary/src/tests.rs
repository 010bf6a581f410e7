use super::*;
use nalgebra::Vector3;

fn close(a: &Vector3<f64>, b: &Vector3<f64>, tol: f64) -> bool {
    (a - b).norm() <= tol
}

/// A small deterministic normal noise source (LCG + Box-Muller), so tests repeat.
struct Noise(u64);
impl Noise {
    fn uniform(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    fn normal(&mut self) -> f64 {
        let (u1, u2) = (self.uniform(), self.uniform());
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }
}

#[test]
fn nominal_direction_is_the_papers() {
    let m = RotaryMachine::nominal(MachineConstants::default());
    for a in [-20.0, 0.0, 15.0, 45.0, 90.0] {
        for c in [0.0, 30.0, 135.0, 270.0] {
            let pose = m.forward(&Axes::new(12.0, -7.0, -150.0, a, c));
            let (sa, ca) = a.to_radians().sin_cos();
            let (sc, cc) = c.to_radians().sin_cos();
            let paper = Vector3::new(sa * sc, sa * cc, ca);
            assert!(close(&pose.direction, &paper, 1e-12), "A {a} C {c}");
        }
    }
}

/// LinuxCNC's xyzac-trt kinematics as published (src/emc/kinematics/trtfuncs.c,
/// `xyzacKinematicsForward`): joints (the tool tip in machine coordinates, A, C in
/// degrees) to the tool tip in the rotated table's coordinates. `rot` is the rotation
/// point (x, y, z rot-point), `dy`, `dz`, `dt` the y-offset, z-offset and tool-offset
/// (the A axis is at y = rot.y + dy, z = rot.z + dz + dt; dz and dt only ever appear
/// as their sum).
fn linuxcnc_xyzac_forward(
    j: [f64; 3],
    a_deg: f64,
    c_deg: f64,
    rot: [f64; 3],
    dy: f64,
    dz: f64,
    dt: f64,
) -> [f64; 3] {
    let (sa, ca) = a_deg.to_radians().sin_cos();
    let (sc, cc) = c_deg.to_radians().sin_cos();
    let dz = dz + dt;
    let (px, py, pz) = (j[0] - rot[0], j[1] - dy - rot[1], j[2] - dz - rot[2]);
    [
        cc * px + sc * ca * py + sc * sa * pz + sc * dy + rot[0],
        -sc * px + cc * ca * py + cc * sa * pz + cc * dy + rot[1],
        -sa * py + ca * pz + dz + rot[2],
    ]
}

/// The same file's `xyzacKinematicsInverse`: the tool tip in table coordinates back to
/// the joints.
fn linuxcnc_xyzac_inverse(
    p: [f64; 3],
    a_deg: f64,
    c_deg: f64,
    rot: [f64; 3],
    dy: f64,
    dz: f64,
    dt: f64,
) -> [f64; 3] {
    let (sa, ca) = a_deg.to_radians().sin_cos();
    let (sc, cc) = c_deg.to_radians().sin_cos();
    let dz = dz + dt;
    let (qx, qy, qz) = (p[0] - rot[0], p[1] - rot[1], p[2] - rot[2]);
    [
        cc * qx - sc * qy + rot[0],
        sc * ca * qx + cc * ca * qy - sa * qz - ca * dy + sa * dz + dy + rot[1],
        sc * sa * qx + cc * sa * qy + ca * qz - sa * dy - ca * dz + dz + rot[2],
    ]
}

#[test]
fn nominal_chain_agrees_with_linuxcnc_xyzac_trt() {
    // Constants with every offset non-zero, so each term is exercised.
    let k = MachineConstants {
        a_axis_y_mm: 12.5,
        a_axis_z_mm: -320.0,
        ac_offset_y_mm: -7.25,
        ac_offset_z_mm: 48.0,
        tool_length_mm: 85.0,
    };
    let m = RotaryMachine::nominal(k);
    // LinuxCNC's table coordinates coincide with the machine's at A = C = 0; ours have
    // their origin on the table face, so they differ by `table_origin`. Its rotation
    // point is on the C axis (we take the table origin), its offsets reach the A axis.
    let o = k.table_origin();
    let rot = [o.x, o.y, o.z];
    let dy = -k.ac_offset_y_mm;
    let dt = 30.0;
    let dz = -k.ac_offset_z_mm - dt;
    for (x, y, z) in [
        (0.0, 0.0, -150.0),
        (40.0, -25.0, -200.0),
        (-80.0, 60.0, -90.0),
    ] {
        for a in [-25.0, 0.0, 10.0, 47.0, 90.0] {
            for c in [0.0, 30.0, 123.0, 300.0] {
                let ours = m.forward(&Axes::new(x, y, z, a, c));
                let tip = [x, y, z - k.tool_length_mm];
                let theirs = linuxcnc_xyzac_forward(tip, a, c, rot, dy, dz, dt);
                let theirs_w = Vector3::from(theirs) - o;
                assert!(
                    close(&ours.position, &theirs_w, 1e-9),
                    "A {a} C {c}: ours {} LinuxCNC {theirs_w}",
                    ours.position
                );
                let back = linuxcnc_xyzac_inverse(theirs, a, c, rot, dy, dz, dt);
                let cmd = m.inverse(&ours, (a, c)).unwrap();
                assert!(close(
                    &Vector3::new(cmd.x, cmd.y, cmd.z - k.tool_length_mm),
                    &Vector3::from(back),
                    1e-9
                ));
                assert!((cmd.a - a).abs() < 1e-9 && wrap_c(cmd.c - c).abs() < 1e-9);
            }
        }
    }
}

fn wrap_c(d: f64) -> f64 {
    machine::wrap_deg(d)
}

#[test]
fn each_location_error_moves_the_table_as_defined() {
    let k = MachineConstants::default();
    let o = k.table_origin();
    // delta_XC = d alone: a point at (r, 0, 0) on the table turns about x = d, so at
    // C = 180° it is at x = d - (r - d) = 2d - r.
    let d = 0.01;
    let m = RotaryMachine::with_errors(
        k,
        LocationErrors {
            delta_xc_mm: d,
            ..LocationErrors::default()
        },
    );
    let p = kinematics::transform_point(&m.table(0.0, 180.0), &Vector3::new(50.0, 0.0, 0.0));
    assert!(
        close(&(p - o), &Vector3::new(2.0 * d - 50.0, 0.0, 0.0), 1e-12),
        "{p}"
    );
    // ... and at C = 0 the table is where it is mounted (zero-angle errors neglected).
    let p0 = kinematics::transform_point(&m.table(0.0, 0.0), &Vector3::new(50.0, 0.0, 0.0));
    assert!(close(&(p0 - o), &Vector3::new(50.0, 0.0, 0.0), 1e-12));
    // delta_ZA = e alone: the table origin turns about the A axis raised by e; at
    // A = 90° it lands (0, e, e) away from its nominal place pA + (0, -zac, yac).
    let e = 0.02;
    let m = RotaryMachine::with_errors(
        k,
        LocationErrors {
            delta_za_mm: e,
            ..LocationErrors::default()
        },
    );
    let p = kinematics::transform_point(&m.table(90.0, 0.0), &Vector3::zeros());
    let nominal = k.a_axis_point() + Vector3::new(0.0, -k.ac_offset_z_mm, k.ac_offset_y_mm);
    assert!(
        close(&(p - nominal), &Vector3::new(0.0, e, e), 1e-12),
        "{}",
        p - nominal
    );
    // alpha_YC = t alone: the C axis leans towards +X; a point 100 mm up the axis at
    // C = 180° goes round it: x = 2 * 100 * t (first order).
    let t = 1e-4_f64;
    let m = RotaryMachine::with_errors(
        k,
        LocationErrors {
            alpha_yc_deg: t.to_degrees(),
            ..LocationErrors::default()
        },
    );
    let p = kinematics::transform_point(&m.table(0.0, 180.0), &Vector3::new(0.0, 0.0, 100.0));
    assert!(
        // second-order terms: 100 mm * t² = 1e-6 mm
        close(&(p - o), &Vector3::new(200.0 * t, 0.0, 100.0), 1e-5),
        "{}",
        p - o
    );
}

#[test]
fn worked_example_of_the_crate_docs() {
    let k = MachineConstants::default();
    let nominal = Axes::new(0.0, 0.0, -190.0, 30.0, 45.0);
    let ideal = RotaryMachine::nominal(k).forward(&nominal);
    // Tip 60 mm above the A axis, turned back by A then C: (0, 60 sin 30°, 60 cos 30° - 60)
    // = (0, 30, -8.0385), then Rz(-45°): (21.2132, 21.2132, -8.0385).
    let h = 30.0 * 0.5f64.sqrt();
    assert!(close(
        &ideal.position,
        &Vector3::new(h, h, 60.0 * 3f64.sqrt() / 2.0 - 60.0),
        1e-9
    ));
    let s = 0.5f64.sqrt() * 0.5;
    assert!(close(
        &ideal.direction,
        &Vector3::new(s, s, 3f64.sqrt() / 2.0),
        1e-12
    ));
    let real = RotaryMachine::with_errors(k, LocationErrors::paper());
    let off = real.forward(&nominal);
    let tip_err = (off.position - ideal.position).norm();
    let dir_err = (off.direction - ideal.direction).norm();
    let cmd = real.command_for(&nominal).unwrap();
    assert!((tip_err - 0.2027).abs() < 1e-4, "{tip_err}");
    assert!((dir_err - 0.000185).abs() < 1e-6, "{dir_err}");
    let expect = [-0.00171, -0.20068, -190.03825, 30.00187, 44.97918];
    let got = [cmd.x, cmd.y, cmd.z, cmd.a, cmd.c];
    for (g, e) in got.iter().zip(expect) {
        assert!((g - e).abs() < 6e-6, "{got:?} vs {expect:?}");
    }
    let fixed = real.forward(&cmd);
    assert!(close(&fixed.position, &ideal.position, 1e-9));
    assert!(close(&fixed.direction, &ideal.direction, 1e-12));
}

#[test]
fn command_for_puts_tip_and_direction_back_over_the_whole_a_range() {
    let k = MachineConstants::default();
    let real = RotaryMachine::with_errors(k, LocationErrors::paper());
    let ideal_m = RotaryMachine::nominal(k);
    for a in [-20.0, 1.0, 15.0, 37.5, 60.0, 90.0, 105.0] {
        for c in [-90.0, 0.0, 30.0, 170.0, 359.0] {
            let nominal = Axes::new(25.0, -40.0, -180.0, a, c);
            let ideal = ideal_m.forward(&nominal);
            let cmd = real.command_for(&nominal).unwrap();
            let got = real.forward(&cmd);
            assert!(
                close(&got.position, &ideal.position, 1e-9),
                "A {a} C {c}: {}",
                got.position - ideal.position
            );
            assert!(
                close(&got.direction, &ideal.direction, 1e-11),
                "A {a} C {c}"
            );
        }
    }
    // At A = 0 the tip is exact; the direction as close as A alone can bring it (C
    // keeps its value), and at C = 0 exactly.
    let nominal = Axes::new(0.0, 0.0, -200.0, 0.0, 0.0);
    let cmd = real.command_for(&nominal).unwrap();
    let got = real.forward(&cmd);
    let ideal = ideal_m.forward(&nominal);
    assert!(close(&got.position, &ideal.position, 1e-9));
    assert!(close(&got.direction, &ideal.direction, 1e-11));
    assert_eq!(cmd.c, 0.0);
}

#[test]
fn command_for_refuses_axes_past_their_limits() {
    let k = MachineConstants::default();
    let mut real = RotaryMachine::with_errors(k, LocationErrors::paper());
    let err = real
        .command_for(&Axes::new(0.0, 0.0, -190.0, 120.0, 0.0))
        .unwrap_err();
    assert!(
        matches!(err, RotaryError::OutOfLimits { axis: 'A', .. }),
        "{err}"
    );
    // A nominal command inside whose correction leaves Z's travel: refused naming Z.
    let nominal = Axes::new(0.0, 0.0, -190.0, 90.0, 0.0);
    let cmd = real.command_for(&nominal).unwrap();
    assert!(
        (cmd.z - nominal.z).abs() > 0.1,
        "delta_ZA moves Z at A = 90"
    );
    let between = (nominal.z + cmd.z) / 2.0;
    real.limits.z = if cmd.z > nominal.z {
        [-250.0, between]
    } else {
        [between, 0.0]
    };
    let err = real.command_for(&nominal).unwrap_err();
    assert!(
        matches!(err, RotaryError::OutOfLimits { axis: 'Z', .. }),
        "{err}"
    );
    assert!(err.to_string().contains("axis Z"));
    let err = real
        .command_for(&Axes::new(f64::NAN, 0.0, -190.0, 0.0, 0.0))
        .unwrap_err();
    assert_eq!(err, RotaryError::NotFinite { axis: 'X' });
}

#[test]
fn sphere_fit_finds_centre_and_radius() {
    let c = Vector3::new(1.0, -2.0, 3.0);
    let r = 13.0;
    // Six points around the upper half, as a probe reaches them.
    let mut pts: Vec<Vector3<f64>> = (0..5)
        .map(|k| {
            let t = (72.0 * k as f64).to_radians();
            let el = 20f64.to_radians();
            c + Vector3::new(t.cos() * el.cos(), t.sin() * el.cos(), el.sin()) * r
        })
        .collect();
    pts.push(c + Vector3::new(0.0, 0.0, r));
    let fit = fit_sphere("ball", &pts).unwrap();
    assert!(close(&Vector3::from(fit.centre), &c, 1e-10));
    assert!((fit.radius_mm - r).abs() < 1e-10);
    assert!(fit.rms_mm < 1e-10);
    check_sphere("ball", &fit, 13.0, 0.005, 0.001).unwrap();
    let err = check_sphere("ball 1 at C 30", &fit, 20.5, 0.005, 0.001).unwrap_err();
    assert!(matches!(err, FitError::RadiusOff { .. }));
    assert!(err.to_string().contains("ball 1 at C 30"));
    // A point 10 um off the surface: the residual shows it and the check refuses it.
    let outward = (pts[2] - c).normalize();
    pts[2] += outward * 0.010;
    let fit = fit_sphere("ball", &pts).unwrap();
    assert!(fit.rms_mm > 0.001);
    assert!(matches!(
        check_sphere("ball", &fit, 13.0, 0.02, 0.001),
        Err(FitError::ResidualOff { .. })
    ));
    // All on one circle: no sphere.
    let flat: Vec<Vector3<f64>> = (0..6)
        .map(|k| {
            let t = (60.0 * k as f64).to_radians();
            Vector3::new(t.cos(), t.sin(), 0.0) * 10.0
        })
        .collect();
    assert!(matches!(
        fit_sphere("flat", &flat),
        Err(FitError::Degenerate { .. })
    ));
    assert!(matches!(
        fit_sphere("three", &flat[..3]),
        Err(FitError::TooFewPoints { n: 3, .. })
    ));
}

#[test]
fn circle_fit_on_a_tilted_quarter_arc() {
    let centre = Vector3::new(10.0, -300.0, 20.0);
    let n = Vector3::new(1.0, 0.002, -0.001).normalize();
    let e1 = n.cross(&Vector3::z()).normalize();
    let e2 = n.cross(&e1);
    let r = 61.0;
    let pts: Vec<Vector3<f64>> = (0..7)
        .map(|k| {
            let t = (15.0 * k as f64).to_radians();
            centre + (e1 * t.cos() + e2 * t.sin()) * r
        })
        .collect();
    let fit = fit_circle("arc", &pts).unwrap();
    assert!(close(&fit.centre_v(), &centre, 1e-8), "{}", fit.centre_v());
    assert!(fit.normal_v().dot(&n).abs() > 1.0 - 1e-14);
    assert!((fit.radius_mm - r).abs() < 1e-8);
    let line: Vec<Vector3<f64>> = (0..5).map(|k| Vector3::x() * k as f64).collect();
    assert!(matches!(
        fit_circle("line", &line),
        Err(FitError::Degenerate { .. })
    ));
}

fn noisy(rows: &[CentreRow], sigma: f64, seed: u64) -> Vec<CentreRow> {
    let mut noise = Noise(seed);
    rows.iter()
        .map(|r| CentreRow {
            x_mm: r.x_mm + sigma * noise.normal(),
            y_mm: r.y_mm + sigma * noise.normal(),
            z_mm: r.z_mm + sigma * noise.normal(),
            ..*r
        })
        .collect()
}

fn assert_identified(got: &LocationErrors, want: &LocationErrors, mm: f64, deg: f64) {
    for ((name, g), (_, w)) in got.named().iter().zip(want.named()) {
        let tol = if name.ends_with("_deg") { deg } else { mm };
        assert!((g - w).abs() <= tol, "{name}: identified {g}, injected {w}");
    }
}

#[test]
fn identification_recovers_injected_errors() {
    let k = MachineConstants::default();
    let injected = LocationErrors::paper();
    let real = RotaryMachine::with_errors(k, injected);
    let rows = centres_of(&real, &Artifact::default());
    assert_eq!(rows.len(), 2 * (12 + 7));
    let id = identify(&rows, &k).unwrap();
    // Exact centres: only the model's second-order terms remain (the small-angle
    // matrices are not quite rigid, so a ball's path is not quite a circle: 22 nm on
    // delta_YA with the paper's 0.03° alpha_ZA).
    assert_identified(&id.errors, &injected, 5e-5, 1e-5);
    // Centres with 0.2 um noise per coordinate (a CMM or the probe's sphere fits).
    let rows = noisy(&rows, 0.0002, 7);
    let id = identify(&rows, &k).unwrap();
    assert_identified(&id.errors, &injected, 0.001, 0.0005);
    for ((name, u), ((_, g), (_, w))) in id
        .uncertainty
        .named()
        .iter()
        .zip(id.errors.named().iter().zip(injected.named()))
    {
        assert!(*u > 0.0, "{name}: no uncertainty");
        assert!((g - w).abs() <= 5.0 * u, "{name}: {g} vs {w}, u {u}");
    }
    for (_, _, c) in &id.circles {
        assert!(c.rms_radial_mm < 0.001 && c.rms_plane_mm < 0.001);
    }
    // The nominal machine identifies as (about) zero.
    let rows = centres_of(&RotaryMachine::nominal(k), &Artifact::default());
    let id = identify(&rows, &k).unwrap();
    assert_identified(&id.errors, &LocationErrors::default(), 1e-9, 1e-9);
}

#[test]
fn identification_refuses_a_missing_sweep() {
    let k = MachineConstants::default();
    let rows: Vec<CentreRow> = centres_of(&RotaryMachine::nominal(k), &Artifact::default())
        .into_iter()
        .filter(|r| !(r.axis == Axis::A && r.ball == 2))
        .collect();
    let err = identify(&rows, &k).unwrap_err();
    assert_eq!(
        err,
        IdentifyError::Missing {
            axis: Axis::A,
            ball: 2
        }
    );
}

#[test]
fn centres_file_round_trip_and_errors() {
    let k = MachineConstants::default();
    let rows = centres_of(
        &RotaryMachine::with_errors(k, LocationErrors::paper()),
        &Artifact::default(),
    );
    let text = write_centres(&rows);
    let back = parse_centres(&text).unwrap();
    assert_eq!(back.len(), rows.len());
    for (a, b) in rows.iter().zip(&back) {
        assert_eq!((a.axis, a.step, a.ball), (b.axis, b.step, b.ball));
        assert!((a.x_mm - b.x_mm).abs() < 1e-6 && (a.z_mm - b.z_mm).abs() < 1e-6);
    }
    let ok = "# from the CMM\naxis,step,angle_deg,ball,x_mm,y_mm,z_mm\n\nC,0,0,1,1.5,2,-3e1\n";
    let r = parse_centres(ok).unwrap();
    assert_eq!(r[0].z_mm, -30.0);
    assert_eq!(r[0].axis, Axis::C);

    let h = "axis,step,angle_deg,ball,x_mm,y_mm,z_mm\n";
    let cases: [(&str, &str); 10] = [
        (
            "C,0,0,1,1e308,2,3\n",
            "line 2, column 5 (x_mm): `1e308` is outside any machine (at most 10 000 mm from zero)",
        ),
        (
            "C,0,0,1,1,2,-20000\n",
            "line 2, column 7 (z_mm): `-20000` is outside any machine",
        ),
        (
            "A,0,1e9,1,1,2,3\n",
            "line 2, column 3 (angle_deg): `1e9` is not an angle of a sweep",
        ),
        (
            "axis,step,angle,ball,x,y,z\n",
            "line 1: expected the header",
        ),
        ("", "no header"),
        ("C,0,0,1,1,2\n", "line 2: 6 fields"),
        (
            "B,0,0,1,1,2,3\n",
            "line 2, column 1 (axis): `B` is not an axis",
        ),
        ("C,0,0,3,1,2,3\n", "line 2, column 4 (ball): `3`"),
        (
            "C,0,0,1,1,nan,3\n",
            "line 2, column 6 (y_mm): `nan` is not a finite",
        ),
        (
            "C,0,0,1,1,2,3\nC,0,30,1,1,2,3\n",
            "line 3: a second row for axis C step 0 ball 1 (first on line 2)",
        ),
    ];
    for (body, want) in cases {
        let text = if body.starts_with("axis") || body.is_empty() {
            body.to_string()
        } else {
            format!("{h}{body}")
        };
        let err = parse_centres(&text).unwrap_err().to_string();
        assert!(err.contains(want), "{text:?}: {err}");
    }
    assert_eq!(parse_centres(h).unwrap_err(), CentresError::Empty);
}

/// A fit given a point no machine can have (1e308 looped the SVD) refuses it at once,
/// naming the point; the same with NaN.
#[test]
fn fits_refuse_points_outside_any_machine() {
    let mut pts: Vec<Vector3<f64>> = (0..8)
        .map(|k| {
            let t = k as f64 * 0.7;
            Vector3::new(50.0 * t.cos(), 50.0 * t.sin(), -200.0)
        })
        .collect();
    assert!(fit_circle("ok", &pts).is_ok());
    for bad in [1e308, -1e300, 1e5, f64::NAN, f64::INFINITY] {
        pts[2].x = bad;
        let e = fit_circle("axis C ball 1", &pts).unwrap_err().to_string();
        assert!(e.contains("axis C ball 1") && e.contains("point 3"), "{e}");
        let e = fit_sphere("ball 1", &pts).unwrap_err().to_string();
        assert!(e.contains("point 3"), "{e}");
    }
}

#[test]
fn sweep_chart_renders() {
    let k = MachineConstants::default();
    let rows = noisy(
        &centres_of(
            &RotaryMachine::with_errors(k, LocationErrors::paper()),
            &Artifact::default(),
        ),
        0.0003,
        3,
    );
    let id = identify(&rows, &k).unwrap();
    let chart = chart::SweepChart {
        rows: &rows,
        identification: &id,
        magnification: 1000.0,
    };
    let svg = plot::render_svg(&chart, 900, 420).unwrap();
    assert!(svg.starts_with("<svg"));
    assert!(svg.contains("C sweep") && svg.contains("A sweep"));
}

/// The errors file's machine constants are the rewrite's: another `--machine` is
/// refused naming what differs, unless forced; a file without them takes the given ones
/// or the built-in ones.
#[test]
fn a_rewrite_uses_the_machine_constants_stored_with_the_errors() {
    let other = MachineConstants {
        a_axis_z_mm: -340.0,
        ac_offset_z_mm: 80.0,
        ..MachineConstants::default()
    };
    let mut v = serde_json::to_value(LocationErrors::paper()).unwrap();
    v["machine"] = serde_json::to_value(other).unwrap();
    let text = v.to_string();
    let stored = MachineConstants::from_errors_json(&text).unwrap();
    assert_eq!(stored, Some(other));
    assert_eq!(MachineConstants::for_errors(stored, None, false), Ok(other));
    assert_eq!(
        MachineConstants::for_errors(stored, Some(other), false),
        Ok(other)
    );
    let e =
        MachineConstants::for_errors(stored, Some(MachineConstants::default()), false).unwrap_err();
    assert!(
        e.contains("a_axis_z_mm -340 in the errors file, -350 given, ac_offset_z_mm 80 in the errors file, 60 given"),
        "{e}"
    );
    assert_eq!(
        MachineConstants::for_errors(stored, Some(MachineConstants::default()), true),
        Ok(MachineConstants::default())
    );
    assert_eq!(
        MachineConstants::for_errors(None, None, false),
        Ok(MachineConstants::default())
    );
    // The stored constants matter: the same point commanded through the two differs.
    let p = Axes::new(10.0, -20.0, -190.0, 30.0, 45.0);
    let a = RotaryMachine::with_errors(other, LocationErrors::paper())
        .command_for(&p)
        .unwrap();
    let b = RotaryMachine::with_errors(MachineConstants::default(), LocationErrors::paper())
        .command_for(&p)
        .unwrap();
    let off = ((a.x - b.x).powi(2) + (a.y - b.y).powi(2) + (a.z - b.z).powi(2)).sqrt();
    assert!(off > 5e-4, "{off} mm {a:?} {b:?}");
    // A file without them; a broken one names the field.
    let plain = serde_json::to_string(&LocationErrors::paper()).unwrap();
    assert_eq!(MachineConstants::from_errors_json(&plain), Ok(None));
    v["machine"]["tool_length_mm"] = serde_json::json!(1e300);
    let e = MachineConstants::from_errors_json(&v.to_string()).unwrap_err();
    assert!(
        e.contains("machine: machine constant tool_length_mm"),
        "{e}"
    );
}

#[test]
fn errors_json_reads_what_identify_writes_and_refuses_the_rest() {
    let e = LocationErrors::paper();
    let text = serde_json::to_string(&e).unwrap();
    assert!(text.contains("\"delta_ZA_mm\":-0.3924"), "{text}");
    assert_eq!(LocationErrors::from_json(&text).unwrap(), e);
    // Extra fields (uncertainty, fits) are ignored.
    let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
    v["uncertainty"] = serde_json::json!({"delta_XC_mm": 0.0001});
    assert_eq!(LocationErrors::from_json(&v.to_string()).unwrap(), e);
    v.as_object_mut().unwrap().remove("alpha_ZA_deg");
    let err = LocationErrors::from_json(&v.to_string()).unwrap_err();
    assert!(err.contains("alpha_ZA_deg"), "{err}");
    v["alpha_ZA_deg"] = serde_json::json!(3.0);
    let err = LocationErrors::from_json(&v.to_string()).unwrap_err();
    assert!(err.contains("alpha_ZA_deg = 3"), "{err}");
}

const PROGRAM: &str = "%\n(5-axis test)\nG21 G90 G94\nG0 X0 Y0 Z-150 A0 C0\nG1 X10 Y-20 Z-190 A30 C45 F500 (first cut)\nA90 C180\nG0 Z-100\n%\n";

#[test]
fn rewrite_replaces_each_point_and_splits_feed_moves() {
    let k = MachineConstants::default();
    let real = RotaryMachine::with_errors(k, LocationErrors::paper());
    let opts = rewrite::RewriteOptions::default();
    let (out, report) = rewrite::rewrite_program(PROGRAM, &real, &opts).unwrap();
    assert_eq!(report.moves, 4);
    // Unchanged lines stay as written.
    assert!(out.starts_with("%\n(5-axis test)\nG21 G90 G94\n"), "{out}");
    assert!(out.contains("F500 (first cut)"), "{out}");
    // The long A move is cut into pieces; every written command is the model's command
    // for its nominal point, to the written decimals.
    assert!(report.pieces_added > 2, "{}", report.pieces_added);
    let reparsed = protocol::nc::Program::parse(&out).unwrap();
    let written: Vec<_> = reparsed
        .blocks
        .iter()
        .filter(|b| b.word('X').is_some())
        .collect();
    assert_eq!(written.len(), report.points.len());
    for (b, p) in written.iter().zip(&report.points) {
        let want = real.command_for(&p.nominal).unwrap();
        let got = [
            b.word('X'),
            b.word('Y'),
            b.word('Z'),
            b.word('A'),
            b.word('C'),
        ]
        .map(|w| w.unwrap().value());
        let want = [want.x, want.y, want.z, want.a, want.c];
        for i in 0..5 {
            let tol = if i < 3 { 0.5e-4 } else { 0.5e-5 };
            assert!(
                (got[i] - want[i]).abs() <= tol + 1e-12,
                "{got:?} vs {want:?}"
            );
        }
    }
    // Between two written points of a feed move, the straight line of commands keeps
    // the tool on the programmed path: the middle of every piece, run on the real
    // machine, is within 1 um of the nominal middle.
    let ideal = RotaryMachine::nominal(k);
    for w in report.points.windows(2) {
        if !w[1].feed_move {
            continue;
        }
        let mid = |a: &Axes, b: &Axes| {
            Axes::new(
                (a.x + b.x) / 2.0,
                (a.y + b.y) / 2.0,
                (a.z + b.z) / 2.0,
                (a.a + b.a) / 2.0,
                (a.c + b.c) / 2.0,
            )
        };
        let got = real.forward(&mid(&w[0].command, &w[1].command));
        let want = ideal.forward(&mid(&w[0].nominal, &w[1].nominal));
        assert!((got.position - want.position).norm() < 0.001);
    }
}

#[test]
fn rewrite_refuses_what_it_cannot_follow_naming_the_line() {
    let real = RotaryMachine::with_errors(MachineConstants::default(), LocationErrors::paper());
    let opts = rewrite::RewriteOptions::default();
    let cases = [
        ("G0 X0 Y0 Z-150 A0 C0\nG91 G1 X1 F500\n", "line 2: incremental"),
        ("G0 X0 Y0 Z-150 A0 C0\nG2 X1 Y1 I1 F500\n", "line 2: arcs"),
        ("G0 X0 Y0 Z-150 A0 C0\nG1 B10 F500\n", "line 2: axis B"),
        ("G0 X0 Y0 Z-150\n", "line 1: axes AC not known"),
        (
            "G0 X0 Y0 Z-150 A0 C0\nG1 A120 F500\n",
            "line 2: axis A: 120.0000 is outside",
        ),
        ("G20\n", "line 1: inches"),
        // What GRBL refuses, refused as the 3-axis rewrite does (one dialect check).
        (
            "G0 X0 Y0 Z-150 A0 C0\nG1 X1 A30\n",
            "line 2: the controller would refuse this block with error:22",
        ),
        (
            "G0 X0 Y0 Z-150 A0 C0\nG1 X1 A30 F0\n",
            "line 2: the controller would refuse this block with error:22",
        ),
        (
            "G0 X0 Y0 Z-150 A0 C0\nG0 X1 X2\n",
            "line 2: the controller would refuse this block with error:25",
        ),
        (
            "G0 X0 Y0 Z-150 A0 C0\nG0 A1 A2\n",
            "line 2: the controller would refuse this block with error:25",
        ),
        (
            "G0 X0 Y0 Z-150 A0 C0\nG0 X1e308\n",
            "line 2: the controller would refuse this block with error:2",
        ),
        (
            "G0 X0 Y0 Z-150 A0 C0\nG0 X1 Q7\n",
            "line 2: the controller would refuse this block with error:20",
        ),
        // G93: each block needs its own F (GRBL), and the pieces of a split move
        // could not keep it.
        (
            "G0 X0 Y0 Z-150 A0 C0\nG93 G1 X1 A10\n",
            "line 2: the controller would refuse this block with error:22",
        ),
        (
            "G0 X0 Y0 Z-150 A0 C0\nG93 G1 X1 A10 F2\n",
            "line 2: inverse time feed (G93) is not supported",
        ),
        (
            "G0 X0 Y0 Z-150 A0 C0\nG0 X0.0000000000000000000000000000000000000000 Y0.0000000000000000000000000000000000000000 Z-150 A0 C0\n",
            "line 2: the controller cannot receive this line",
        ),
    ];
    for (text, want) in cases {
        let err = rewrite::rewrite_program(text, &real, &opts)
            .unwrap_err()
            .to_string();
        assert!(err.contains(want), "{text:?}: {err}");
    }
}
