//! Hand-computed vectors for every figure (worked out on paper from the definitions in
//! lib.rs), including the cases an open implementation gets wrong: the bidirectional E
//! larger than both directions' E, R's largest R_i at a position where neither
//! direction's R_i is largest, unequal numbers of positions and runs.

use super::*;
use crate::csv_io::{read, write, CsvError};
use crate::plan::{min_positions, targets, Cycle, CycleKind, PlanError, Step};

fn ms(axis: &str, data: &[(f64, &[f64], &[f64])]) -> Vec<Measurement> {
    let mut out = Vec::new();
    for (i, (t, up, down)) in data.iter().enumerate() {
        for (direction, v) in [(Direction::Up, up), (Direction::Down, down)] {
            for (j, &d) in v.iter().enumerate() {
                out.push(Measurement {
                    axis: axis.into(),
                    position_index: i + 1,
                    target_mm: *t,
                    run: j + 1,
                    direction,
                    deviation_um: d,
                });
            }
        }
    }
    out
}

const S25: f64 = 1.581_138_830_084_189_8; // sqrt(2.5)
const S20: f64 = 4.472_135_954_999_579; // sqrt(20)

fn close(a: f64, b: f64) {
    assert!((a - b).abs() < 1e-9, "{a} != {b}");
}

/// Five positions, five runs: means ↑ 3, 0, 10, 2, -3 and ↓ 1, 0, -10, 2, -2.
fn five() -> Vec<Measurement> {
    ms(
        "X",
        &[
            (0.0, &[1.0, 2.0, 3.0, 4.0, 5.0], &[-1.0, 0.0, 1.0, 2.0, 3.0]),
            (10.0, &[0.0; 5], &[0.0; 5]),
            (20.0, &[10.0; 5], &[-10.0; 5]),
            (30.0, &[0.0, 0.0, 0.0, 0.0, 10.0], &[2.0; 5]),
            (40.0, &[-3.0; 5], &[-4.0, -3.0, -2.0, -1.0, 0.0]),
        ],
    )
}

#[test]
fn per_position_figures() {
    let e = evaluate(&five()).unwrap();
    let p = &e.positions;
    // Position 1: x̄↑ 3, x̄↓ 1, s = sqrt(10/4), B_i 2, R_i = 4 s + 2.
    close(p[0].mean_up_um, 3.0);
    close(p[0].mean_down_um, 1.0);
    close(p[0].mean_um, 2.0);
    close(p[0].s_up_um, S25);
    close(p[0].s_down_um, S25);
    close(p[0].reversal_um, 2.0);
    close(p[0].r_up_um, 4.0 * S25);
    close(p[0].r_down_um, 4.0 * S25);
    close(p[0].r_um, 4.0 * S25 + 2.0);
    // Position 3: no scatter, R_i is |B_i| = 20.
    close(p[2].reversal_um, 20.0);
    close(p[2].r_um, 20.0);
    // Position 4: one outlier; s↑ = sqrt((4·4 + 64)/4); R_i is R_i↑, not 2s↑ + 2s↓ + |B|.
    close(p[3].s_up_um, S20);
    close(p[3].r_up_um, 4.0 * S20);
    close(p[3].r_um, 4.0 * S20);
    // Position 5: a negative reversal, R_i = R_i↓ = 4 s↓ > 2 s↓ + |B_i|.
    close(p[4].reversal_um, -1.0);
    close(p[4].r_um, 4.0 * S25);
    close(p[4].mean_um, -2.5);
}

#[test]
fn axis_figures_by_hand() {
    let f = evaluate(&five()).unwrap().figures;
    close(f.e_up, 13.0); // 10 - (-3)
    close(f.e_down, 12.0); // 2 - (-10)
                           // Bidirectional E over both directions at once: 10 - (-10), larger than either.
    close(f.e, 20.0);
    assert!(f.e > f.e_up && f.e > f.e_down);
    close(f.m, 4.5); // x̄ = 2, 0, 0, 2, -2.5
    close(f.b, 20.0);
    close(f.mean_reversal, 21.0 / 5.0); // (2 + 0 + 20 + 0 - 1) / 5 positions
    close(f.r_up, 4.0 * S20);
    close(f.r_down, 4.0 * S25);
    // R is the largest R_i (position 3, from |B_i|), where neither R_i↑ nor R_i↓ peaks.
    close(f.r, 20.0);
    assert!(f.r > f.r_up && f.r > f.r_down);
    // A↑: max(x̄↑ + 2s↑) = 2 + 2·sqrt(20) at position 4, min(x̄↑ - 2s↑) = 2 - 2·sqrt(20).
    close(f.a_up, 4.0 * S20);
    // A↓: max(x̄↓ + 2s↓) = 1 + 2·sqrt(2.5) (position 1), min = -10 (position 3).
    close(f.a_down, 11.0 + 2.0 * S25);
    // A: 2 + 2·sqrt(20) down to -10.
    close(f.a, 12.0 + 2.0 * S20);
}

#[test]
fn means_divide_by_each_directions_runs_not_by_positions() {
    // Six positions, seven runs up, six down at the first position: n differs from m
    // and between directions.
    let up7 = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0];
    let down6 = [0.0, 0.0, 0.0, 0.0, 0.0, 6.0];
    let z7 = [0.0; 7];
    let data: Vec<(f64, &[f64], &[f64])> = vec![
        (5.0, &up7, &down6),
        (15.0, &z7, &z7),
        (25.0, &z7, &z7),
        (35.0, &z7, &z7),
        (45.0, &z7, &z7),
        (55.0, &z7, &z7),
    ];
    let e = evaluate(&ms("Y", &data)).unwrap();
    let p = &e.positions[0];
    assert_eq!((p.runs_up, p.runs_down), (7, 6));
    close(p.mean_up_um, 4.0);
    close(p.s_up_um, (28.0f64 / 6.0).sqrt());
    close(p.mean_down_um, 1.0);
    close(p.s_down_um, 6.0f64.sqrt()); // (5·1 + 25) / 5
    close(e.figures.mean_reversal, 3.0 / 6.0);
    close(e.figures.e_up, 4.0);
    assert_eq!(e.axis, "Y");
}

#[test]
fn evaluation_refuses_what_the_standard_does_not_allow() {
    let mut m = five();
    m.retain(|q| !(q.position_index == 2 && q.direction == Direction::Down));
    assert!(matches!(
        evaluate(&m),
        Err(EvalError::MissingDirection {
            position_index: 2,
            direction: Direction::Down,
            ..
        })
    ));
    let mut m = five();
    m.retain(|q| !(q.position_index == 4 && q.run == 5 && q.direction == Direction::Up));
    assert!(matches!(
        evaluate(&m),
        Err(EvalError::TooFewRuns {
            position_index: 4,
            found: 4,
            ..
        })
    ));
    let mut m = five();
    m.retain(|q| q.position_index != 5);
    assert_eq!(evaluate(&m), Err(EvalError::TooFewPositions { found: 4 }));
    let mut m = five();
    m[3].axis = "Y".into();
    assert!(matches!(evaluate(&m), Err(EvalError::MixedAxes(..))));
    assert_eq!(evaluate(&[]), Err(EvalError::Empty));
}

#[test]
fn uncertainty_budget_worked_example() {
    // s of 0.0, 0.2, 0.4 is 0.2 (n - 1).
    let u = Uncertainty::new(1.0, &[0.0, 0.2, 0.4]);
    close(u.localization_s_um, 0.2);
    close(u.expanded_um, 2.0 * (0.25f64 + 0.04).sqrt());
    assert_eq!(u.localization_frames, 3);
}

#[test]
fn targets_are_irregular_cover_the_travel_and_meet_the_minimum() {
    assert_eq!(
        targets(10.0, 90.0, None).unwrap(),
        vec![10.0, 29.666, 50.748, 74.663, 90.0]
    );
    assert_eq!(min_positions(80.0), 5);
    assert_eq!(min_positions(1200.0), 6);
    let t = targets(0.0, 1200.0, None).unwrap();
    assert_eq!(t.len(), 6);
    let gaps: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
    assert_eq!(t, vec![0.0, 235.988, 488.972, 775.95, 952.922, 1200.0]);
    // Increasing, none two alike (no common period), each within 0.4 .. 1.6 p.
    for g in &gaps {
        assert!(*g > 0.4 * 240.0 && *g < 1.6 * 240.0, "{gaps:?}");
    }
    for a in 0..gaps.len() {
        for b in a + 1..gaps.len() {
            assert!((gaps[a] - gaps[b]).abs() > 1.0, "{gaps:?}");
        }
    }
    assert!(matches!(
        targets(0.0, 1200.0, Some(5)),
        Err(PlanError::TooFewPositions { needed: 6, .. })
    ));
    assert!(matches!(
        targets(5.0, 5.0, None),
        Err(PlanError::EmptyTravel { .. })
    ));
}

#[test]
fn linear_cycle_overruns_before_each_reversal() {
    let c = Cycle::new(vec![1.0, 2.0, 3.0, 4.0, 5.0], 5, 0.5, CycleKind::Linear).unwrap();
    let s = c.steps();
    assert_eq!(s.len(), 5 * (2 + 10));
    assert_eq!(c.measurements(), 50);
    assert_eq!(s[0], Step::Travel { at_mm: 0.5 });
    assert_eq!(
        s[1],
        Step::Measure {
            position: 0,
            run: 1,
            direction: Direction::Up,
            at_mm: 1.0
        }
    );
    assert_eq!(s[6], Step::Travel { at_mm: 5.5 });
    assert_eq!(
        s[7],
        Step::Measure {
            position: 4,
            run: 1,
            direction: Direction::Down,
            at_mm: 5.0
        }
    );
    assert_eq!(s[12], Step::Travel { at_mm: 0.5 });
    // Every measurement is approached from its own side: the position before it is
    // below the target for ↑ and above it for ↓.
    let mut at = 0.0;
    for step in &s {
        match *step {
            Step::Travel { at_mm } => at = at_mm,
            Step::Measure {
                direction, at_mm, ..
            } => {
                match direction {
                    Direction::Up => assert!(at < at_mm),
                    Direction::Down => assert!(at > at_mm),
                }
                at = at_mm;
            }
        }
    }
    let p = Cycle::new(
        vec![1.0, 2.0, 3.0, 4.0, 5.0],
        5,
        0.5,
        CycleKind::PilgrimStep,
    )
    .unwrap();
    let s = p.steps();
    assert_eq!(s.len(), 100);
    assert_eq!(s[0], Step::Travel { at_mm: 0.5 });
    assert_eq!(s[2], Step::Travel { at_mm: 0.5 });
    assert_eq!(s[50], Step::Travel { at_mm: 5.5 });
    assert!(matches!(
        Cycle::new(vec![1.0, 2.0, 3.0, 4.0, 5.0], 4, 0.5, CycleKind::Linear),
        Err(PlanError::TooFewRuns(4))
    ));
    assert!(matches!(
        Cycle::new(vec![1.0, 2.0, 3.0, 4.0], 5, 0.5, CycleKind::Linear),
        Err(PlanError::TooFewPositions { .. })
    ));
}

#[test]
fn csv_round_trip_and_evaluation_from_a_file() {
    let m = five();
    let text = write(&m);
    assert!(text.starts_with("axis,position_index,target_mm,run,direction,deviation_um\n"));
    assert!(text.contains("\nX,3,20.0000,2,-,-10.000\n"), "{text}");
    let back = read(&text).unwrap();
    assert_eq!(back, m);
    // Columns in another order, an extra column, spaces, an empty line.
    let other = "run, direction ,deviation_um,axis,position_index,target_mm,time\n\n".to_string()
        + &m.iter()
            .map(|q| {
                format!(
                    "{}, {},{},{},{},{},12:00\n",
                    q.run,
                    q.direction.sign(),
                    q.deviation_um,
                    q.axis,
                    q.position_index,
                    q.target_mm
                )
            })
            .collect::<String>();
    assert_eq!(read(&other).unwrap(), m);
}

fn err(text: &str) -> CsvError {
    read(text).unwrap_err()
}

#[test]
fn csv_errors_name_the_line() {
    let good = write(&five());
    let lines: Vec<&str> = good.lines().collect();
    let with = |k: usize, new: &str| {
        let mut l = lines.clone();
        l[k] = new;
        l.join("\n")
    };
    // Line 4 is position 1, run 3, up.
    assert_eq!(lines[3], "X,1,0.0000,3,+,3.000");
    let e = err(&with(3, "X,1,0.0000,3,+,abc"));
    assert_eq!(
        e.to_string(),
        "line 4, column deviation_um: `abc` is not a number"
    );
    let e = err(&with(3, "X,1,0.0000,3,+,NaN"));
    assert!(matches!(e, CsvError::Field { line: 4, .. }), "{e}");
    // Finite but absurd: refused naming line and column (1e308 looped the chart code).
    let e = err(&with(3, "X,1,0.0000,3,+,1e308"));
    assert_eq!(
        e.to_string(),
        "line 4, column deviation_um: `1e308` is not a positioning deviation (at most 100 000 um, 100 mm, either way)"
    );
    let e = err(&with(3, "X,1,-2e5,3,+,3"));
    assert!(
        matches!(
            e,
            CsvError::Field {
                line: 4,
                column: "target_mm",
                ..
            }
        ),
        "{e}"
    );
    let e = err(&with(3, "X,1,0.0000,3,up,3"));
    assert!(matches!(
        e,
        CsvError::Field {
            line: 4,
            column: "direction",
            ..
        }
    ));
    let e = err(&with(3, "X,0,0.0000,3,+,3"));
    assert!(matches!(
        e,
        CsvError::Field {
            line: 4,
            column: "position_index",
            ..
        }
    ));
    let e = err(&with(3, "X,1,0.0000,2,+,3"));
    assert_eq!(
        e.to_string(),
        "line 4 repeats position 1, run 2, direction + of line 3"
    );
    let e = err(&with(3, "X,1,0.5,3,+,3"));
    assert!(
        matches!(
            e,
            CsvError::TargetMismatch {
                line: 4,
                first_line: 2,
                ..
            }
        ),
        "{e}"
    );
    let e = err(&with(3, "Y,1,0.0000,3,+,3"));
    assert!(matches!(e, CsvError::MixedAxes { line: 4, .. }), "{e}");
    let e = err(&with(3, "X,1,0.0000,3,+"));
    assert!(matches!(e, CsvError::Syntax { line: 4, .. }), "{e}");
    let e = err(&with(0, "axis,position_index,target_mm,run,direction"));
    assert_eq!(e, CsvError::MissingColumn("deviation_um"));
    // Position 2 is on target 10; position 3 given the same target.
    let mut l = lines.clone();
    let moved: Vec<String> = l
        .iter()
        .map(|s| s.replace("X,3,20.0000", "X,3,10.0000"))
        .collect();
    l = moved.iter().map(String::as_str).collect();
    assert!(matches!(
        err(&l.join("\n")),
        CsvError::SharedTarget {
            position_index: 3,
            other_index: 2,
            ..
        }
    ));
    // Without position 2's ↓ rows (lines 17..21): named with its lines.
    let no_down: Vec<&str> = lines
        .iter()
        .copied()
        .filter(|s| !s.starts_with("X,2,10.0000,") || s.contains(",+,"))
        .collect();
    assert_eq!(
        err(&no_down.join("\n")).to_string(),
        "position 2 (lines 12, 13, 14, 15, 16) has no runs in the - direction"
    );
    let four_runs: Vec<&str> = lines
        .iter()
        .copied()
        .filter(|s| *s != "X,5,40.0000,5,-,0.000")
        .collect();
    assert!(matches!(
        err(&four_runs.join("\n")),
        CsvError::TooFewRuns {
            position_index: 5,
            direction: Direction::Down,
            found: 4,
            ..
        }
    ));
    let four_positions: Vec<&str> = lines
        .iter()
        .copied()
        .filter(|s| !s.starts_with("X,5,"))
        .collect();
    assert_eq!(
        err(&four_positions.join("\n")),
        CsvError::TooFewPositions { found: 4 }
    );
    assert_eq!(err(lines[0]), CsvError::Empty);
}

#[test]
fn result_json_uses_the_standards_names() {
    let e = evaluate(&five()).unwrap();
    let u = Uncertainty::new(1.0, &[0.0, 0.2, 0.4]);
    let v = report::result_json(&e, Some(&u));
    for k in [
        "A_um",
        "A_up_um",
        "A_down_um",
        "B_um",
        "mean_reversal_um",
        "R_um",
        "R_up_um",
        "R_down_um",
        "E_um",
        "E_up_um",
        "E_down_um",
        "M_um",
    ] {
        assert!(v[k].is_f64(), "{k}");
    }
    assert_eq!(v["E_um"], 20.0);
    assert_eq!(v["R_um"], 20.0);
    assert_eq!(v["B_i_um"][2], 20.0);
    assert_eq!(v["target_mm"].as_array().unwrap().len(), 5);
    assert_eq!(v["axis"], "X");
    assert_eq!(v["positions"], 5);
    assert!(v["uncertainty"]["expanded_um"].is_f64());
}

#[test]
fn charts_and_html_report() {
    let before = evaluate(&five()).unwrap();
    let mut m = five();
    for q in &mut m {
        q.deviation_um *= 0.1;
    }
    let after = evaluate(&m).unwrap();
    let chart = report::DeviationChart {
        title: "X before / after".into(),
        series: vec![
            report::Series {
                label: "before",
                evaluation: &before,
            },
            report::Series {
                label: "after",
                evaluation: &after,
            },
        ],
    };
    // An evaluation holding an absurd figure still draws (the axes are clamped): the
    // chart code looped on a deviation of 1e308 before.
    let mut wild = five();
    wild[0].deviation_um = 1e308;
    let wild = evaluate(&wild).unwrap();
    let wild_chart = report::DeviationChart {
        title: "wild".into(),
        series: vec![report::Series {
            label: "wild",
            evaluation: &wild,
        }],
    };
    assert!(plot::render_svg(&wild_chart, 400, 300).is_ok());
    let svg = plot::render_svg(&chart, 800, 500).unwrap();
    assert!(svg.contains("before: mean up (+)") && svg.contains("after: mean down (-)"));
    let png = plot::render_png(&chart, 800, 500).unwrap();
    assert_eq!(&png[1..4], b"PNG");
    let html = report::html(
        "ISO 230-2 <X>",
        &[
            report::Tested {
                label: "before",
                evaluation: &before,
                uncertainty: None,
            },
            report::Tested {
                label: "after",
                evaluation: &after,
                uncertainty: None,
            },
        ],
        std::slice::from_ref(&svg),
        &["machine time 12 s".into()],
    );
    assert!(html.contains("<svg") && html.contains("ISO 230-2 &lt;X&gt;"));
    assert!(
        html.contains("<td>20.000</td><td>2.000</td>"),
        "E before and after"
    );
}
