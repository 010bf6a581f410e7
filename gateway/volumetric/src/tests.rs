use super::*;

/// The README's worked example: E_XX(250) = 5 µm, E_CX(250) = 10 µrad, E_CY(100) =
/// 10 µrad, E_AZ(50) = 10 µrad (all linear from 0 at position 0), tool offset (0, 0, 100)
/// mm, command (250, 100, 50) mm.
pub(crate) fn worked_example(structure: Structure) -> Model {
    let mut m = Model::zero(structure, [500.0, 400.0, 400.0]);
    m.file.tool_offset_mm = [0.0, 0.0, 100.0];
    m.file.tables[0].errors[1][0] = 0.010;
    m.file.tables[0].errors[1][5] = 20e-6;
    m.file.tables[1].errors[1][5] = 40e-6;
    m.file.tables[2].errors[1][3] = 80e-6;
    m
}

#[test]
fn worked_examples_per_structure() {
    // Hand-computed from the first-order form in the crate docs (µm).
    let expected = [
        (Structure::Fxyz, [4.0, -1.0, 0.0]),
        (Structure::Xfyz, [-4.0, -3.5, 0.0]),
        (Structure::Xyfz, [-3.0, -3.5, 0.0]),
        (Structure::Xyzf, [-3.0, -1.0, 0.0]),
    ];
    for (s, want) in expected {
        let m = worked_example(s);
        let q = [250.0, 100.0, 50.0];
        let fo = m.error_first_order(q).unwrap();
        let ex = m.error_exact(q).unwrap();
        for k in 0..3 {
            assert!(
                (fo[k] * 1e3 - want[k]).abs() < 1e-9,
                "{s} first order {fo:?}"
            );
            assert!((ex[k] * 1e3 - want[k]).abs() < 1e-4, "{s} exact {ex:?}");
        }
    }
}

#[test]
fn error_free_machine_has_no_error_and_offsets_enter_the_nominal() {
    for s in Structure::ALL {
        let mut m = Model::zero(s, [500.0, 400.0, 400.0]);
        m.file.tool_offset_mm = [1.0, 2.0, 150.0];
        m.file.work_offset_mm = [10.0, 20.0, 5.0];
        let rel = m.relative_htm([100.0, 200.0, 300.0]).unwrap();
        let p = kinematics::position(&rel);
        assert!(
            (p - Vector3::new(91.0, 182.0, 445.0)).norm() < 1e-12,
            "{s}: {p}"
        );
        assert_eq!(m.error_exact([100.0, 200.0, 300.0]).unwrap(), [0.0; 3]);
    }
}

#[test]
fn squareness_enters_with_the_documented_signs() {
    let mut m = Model::zero(Structure::Xyfz, [500.0, 400.0, 400.0]);
    m.file.squareness_rad = [10e-6, 20e-6, 30e-6];
    let e = m.error_exact([0.0, 100.0, 200.0]).unwrap();
    // (-E_C0Y y + E_B0Z z, -E_A0Z z, 0) = (-1 + 4, -6, 0) µm.
    assert!((e[0] * 1e3 - 3.0).abs() < 1e-3, "{e:?}");
    assert!((e[1] * 1e3 + 6.0).abs() < 1e-3, "{e:?}");
    assert!(e[2].abs() < 1e-6);
}

/// Smooth tables of realistic size: positioning ~30 µm, straightness ~10 µm, angles
/// ~30 µrad, squareness ~30 µrad.
pub(crate) fn realistic(structure: Structure) -> Model {
    let travel = [500.0, 400.0, 400.0];
    let mut m = Model::zero(structure, travel);
    m.file.tool_offset_mm = [5.0, -3.0, 150.0];
    m.file.work_offset_mm = [-20.0, 10.0, 30.0];
    m.file.squareness_rad = [30e-6, -25e-6, 20e-6];
    for a in 0..3 {
        let n = 41;
        let l = travel[a];
        let t = &mut m.file.tables[a];
        t.positions_mm = (0..n).map(|i| l * i as f64 / (n - 1) as f64).collect();
        t.errors = t
            .positions_mm
            .iter()
            .map(|&q| {
                let u = q / l;
                let wave = |k: f64, ph: f64| (std::f64::consts::TAU * k * u + ph).sin() - ph.sin();
                [
                    0.030 * u + 0.004 * wave(2.0, 0.3 + a as f64),
                    0.010 * wave(1.0, 0.7 * a as f64),
                    -0.008 * wave(1.5, 1.1),
                    25e-6 * wave(1.0, 0.2),
                    -30e-6 * wave(0.8, 0.9 + a as f64),
                    28e-6 * wave(1.2, 0.4),
                ]
            })
            .collect();
    }
    m
}

#[test]
fn first_order_matches_exact_within_0_1_um_over_the_volume() {
    for s in Structure::ALL {
        let m = realistic(s);
        let mut worst: f64 = 0.0;
        let mut biggest: f64 = 0.0;
        for i in 0..=10 {
            for j in 0..=8 {
                for k in 0..=8 {
                    let q = [50.0 * i as f64, 50.0 * j as f64, 50.0 * k as f64];
                    let a = m.error_exact(q).unwrap();
                    let b = m.error_first_order(q).unwrap();
                    for c in 0..3 {
                        worst = worst.max((a[c] - b[c]).abs());
                        biggest = biggest.max(a[c].abs());
                    }
                }
            }
        }
        assert!(worst * 1e3 <= 0.1, "{s}: {} µm", worst * 1e3);
        // The comparison means something: the errors themselves are tens of µm.
        assert!(biggest * 1e3 > 20.0, "{s}: {biggest}");
    }
}

#[test]
fn command_for_puts_the_tool_on_the_nominal_point() {
    for s in Structure::ALL {
        let m = realistic(s);
        let target = [123.0, 321.0, 222.0];
        let c = m.command_for(target).unwrap();
        let e = m.error_exact(c).unwrap();
        for k in 0..3 {
            assert!((c[k] + e[k] - target[k]).abs() < 2e-9, "{s}");
        }
        assert!((c[0] - target[0]).abs() > 1e-3, "the command is corrected");
    }
}

#[test]
fn outside_the_travel_is_refused_not_extrapolated() {
    let m = realistic(Structure::Xyfz);
    let e = m.command_for([500.5, 10.0, 10.0]).unwrap_err();
    assert!(
        matches!(e, VolError::OutsideTravel { axis: 'X', .. }),
        "{e}"
    );
    assert!(m.error_exact([10.0, -0.1, 10.0]).is_err());
    assert!(m.error_first_order([10.0, 10.0, f64::NAN]).is_err());
    // At the end of X the positioning error (+30 µm) asks for a command beyond 500 mm.
    let e = m.command_for([500.0, 10.0, 10.0]).unwrap_err();
    assert!(
        matches!(e, VolError::OutsideTravel { axis: 'X', .. }),
        "{e}"
    );
}

#[test]
fn interpolation_is_linear_between_rows() {
    let m = worked_example(Structure::Xyfz);
    let v = m.axis_errors(0, 125.0).unwrap();
    assert!((v[0] - 0.0025).abs() < 1e-15 && (v[5] - 5e-6).abs() < 1e-18);
}

#[test]
fn the_terms_add_up_to_the_first_order_error() {
    for s in Structure::ALL {
        let m = realistic(s);
        let q = [321.0, 123.0, 234.0];
        let terms = m.terms(q).unwrap();
        let fo = m.error_first_order(q).unwrap();
        for c in 0..3 {
            let sum: f64 = terms.iter().map(|v| v[c]).sum();
            assert!((sum - fo[c]).abs() < 1e-15, "{s}");
        }
    }
}
