//! The interpreter with grblHAL's extra axes A B C (rotary, degrees).

use super::super::codes::status as e;
use super::{filter_bytes, Action, Interpreter, Rate};

fn run<const N: usize>(i: &mut Interpreter<N>, l: &str) -> Result<Vec<Action<N>>, u8> {
    let (f, over) = filter_bytes(l.as_bytes());
    assert!(!over);
    i.execute(&f, false)
}

fn target<const N: usize>(actions: &[Action<N>]) -> [f64; N] {
    match actions.last() {
        Some(Action::Move { target, .. }) => *target,
        other => panic!("no move: {other:?}"),
    }
}

#[test]
fn six_axes_read_a_b_c_in_report_order() {
    let mut i = Interpreter::<6>::with_axes();
    let a = run(&mut i, "G0 X1 A30 C-90").unwrap();
    assert_eq!(
        a,
        vec![Action::Move {
            target: [1.0, 0.0, 0.0, 30.0, 0.0, -90.0],
            rate: Rate::Rapid,
            line_number: None,
            jog: false,
        }]
    );
    assert_eq!(
        target(&run(&mut i, "G1 B12.5 F100").unwrap()),
        [1.0, 0.0, 0.0, 30.0, 12.5, -90.0]
    );
}

#[test]
fn inches_scale_linear_axes_only() {
    // G20: X1 is 25.4 mm, A10 stays 10 degrees.
    let mut i = Interpreter::<4>::with_axes();
    let t = target(&run(&mut i, "G20 G0 X1 A10").unwrap());
    assert_eq!(t, [25.4, 0.0, 0.0, 10.0]);
}

#[test]
fn letters_beyond_the_axes_are_unsupported() {
    let mut three = Interpreter::new();
    assert_eq!(run(&mut three, "G0 A1"), Err(e::UNSUPPORTED_COMMAND));
    let mut four = Interpreter::<4>::with_axes();
    assert_eq!(run(&mut four, "G0 X1 B1"), Err(e::UNSUPPORTED_COMMAND));
    assert_eq!(
        four,
        Interpreter::<4>::with_axes(),
        "refused blocks change nothing"
    );
    let mut six_as_four = Interpreter::<6>::with_axes().restrict_axes(4);
    assert_eq!(run(&mut six_as_four, "G0 B1"), Err(e::UNSUPPORTED_COMMAND));
    six_as_four.reset();
    assert_eq!(six_as_four.axes, 4, "a reset keeps the build's axes");
    let mut five = Interpreter::<5>::with_axes();
    assert_eq!(run(&mut five, "G0 C1"), Err(e::UNSUPPORTED_COMMAND));
    assert!(run(&mut five, "G0 B1").is_ok());
}

#[test]
fn rotary_words_follow_the_grbl_rules_of_axis_words() {
    let mut i = Interpreter::<6>::with_axes();
    assert_eq!(run(&mut i, "G0 A1 A2"), Err(e::WORD_REPEATED));
    assert_eq!(run(&mut i, "G43.1 A1"), Err(e::G43_DYNAMIC_AXIS_ERROR));
    assert_eq!(run(&mut i, "G80 C1"), Err(e::AXIS_WORDS_EXIST));
    // G91: increments; G92: work offset on A; G53 ignores it.
    run(&mut i, "G0 A10").unwrap();
    assert_eq!(target(&run(&mut i, "G91 G0 A5").unwrap())[3], 15.0);
    run(&mut i, "G90 G92 A0").unwrap();
    assert_eq!(i.wco()[3], 15.0);
    assert_eq!(target(&run(&mut i, "G0 A10").unwrap())[3], 25.0);
    assert_eq!(target(&run(&mut i, "G53 G0 A10").unwrap())[3], 10.0);
    // G10 L2 P1 C: stored in G54, the active system.
    run(&mut i, "G92.1").unwrap();
    run(&mut i, "G10 L2 P1 C45").unwrap();
    assert_eq!(i.stored[0][5], 45.0);
    assert_eq!(target(&run(&mut i, "G0 C0").unwrap())[5], 45.0);
}

#[test]
fn arcs_move_rotary_axes_in_proportion() {
    // Quarter circle of radius 10 in XY from (10,0) to (0,10) with A 0 -> 90: every
    // chord end has A = 90 * (angle swept / 90 degrees).
    let mut i = Interpreter::<4>::with_axes();
    run(&mut i, "G0 X10").unwrap();
    let points = run(&mut i, "G3 X0 Y10 I-10 J0 A90 F500").unwrap();
    assert!(points.len() > 2);
    for p in &points {
        let Action::Move { target: t, .. } = p else {
            panic!("{p:?}")
        };
        let swept = t[1].atan2(t[0]).to_degrees();
        assert!((t[3] - swept).abs() < 1e-9, "{t:?}");
    }
    assert_eq!(target(&points), [0.0, 10.0, 0.0, 90.0]);
}

#[test]
fn probe_targets_carry_rotary_axes() {
    let mut i = Interpreter::<6>::with_axes();
    let a = run(&mut i, "G38.2 Z-5 C30 F100").unwrap();
    assert_eq!(
        a,
        vec![Action::Probe {
            target: [0.0, 0.0, -5.0, 0.0, 0.0, 30.0],
            feed: 100.0,
            toward: true,
            fail_is_error: true,
        }]
    );
}
