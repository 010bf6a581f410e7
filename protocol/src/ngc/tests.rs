use super::*;

fn flats(text: &str) -> Vec<Vec<(char, f64)>> {
    expand(text, Bounds::default())
        .unwrap()
        .into_iter()
        .map(|f| f.words)
        .collect()
}

fn moves(text: &str) -> Vec<Action> {
    interpret(text, &Start::default(), Bounds::default())
        .unwrap()
        .into_iter()
        .flat_map(|s| s.actions)
        .filter(|a| {
            matches!(
                a,
                Action::Rapid { .. } | Action::Linear { .. } | Action::Arc { .. }
            )
        })
        .collect()
}

fn refused(text: &str) -> NgcError {
    interpret(text, &Start::default(), Bounds::default()).unwrap_err()
}

#[test]
fn expressions_follow_linuxcncs_precedence_and_functions() {
    let v = |e: &str| flats(&format!("x[{e}]\n"))[0][0].1;
    assert_eq!(v("1 + 2 * 3"), 7.0);
    assert_eq!(v("2 ** 3 ** 2"), 64.0); // left-associative
    assert_eq!(v("-7 mod 3"), 2.0); // always positive
    assert_eq!(v("1 + 1 eq 2"), 1.0);
    assert_eq!(v("1 eq 1.0000001"), 1.0); // TOLERANCE_EQUAL
    assert_eq!(v("0 or 3 and 0"), 0.0); // same precedence, left to right
    assert!((v("atan[1]/[1]") - 45.0).abs() < 1e-12);
    assert_eq!(v("round[-2.5]"), -3.0);
    assert_eq!(v("fix[-2.5] + fup[2.1]"), 0.0);
    assert!((v("sin[30]") - 0.5).abs() < 1e-15);
    assert_eq!(
        flats("x-[1+1] y-#1\n#1=4\n".replace("y-#1\n", "\n").as_str())[0][0].1,
        -2.0
    );
}

#[test]
fn settings_take_effect_after_the_line() {
    let f = flats("#1=1\n#1=2 #2=#1\nx#2\n");
    assert_eq!(f, vec![vec![('x', 1.0)]]);
}

#[test]
fn subroutines_loops_and_conditions_expand() {
    let text = "o<sq> sub\n  g1 x[#1] f100\n  o<sq> return [#1 * 2]\n  g1 x99\no<sq> endsub\n\
                #<n> = 0\no1 while [#<n> lt 3]\n  #<n> = [#<n> + 1]\n  o2 if [#<n> eq 2]\n    o1 continue\n  o2 endif\n  o<sq> call [#<n>]\n  x#<_value>\no1 endwhile\n\
                o3 repeat [2]\n y1\no3 endrepeat\no4 do\n z1\no4 while [0]\nm2\nx5\n";
    let f = flats(text);
    let xs: Vec<f64> = f
        .iter()
        .flat_map(|w| w.iter().filter(|(l, _)| *l == 'x').map(|(_, v)| *v))
        .collect();
    assert_eq!(xs, vec![1.0, 2.0, 3.0, 6.0]);
    assert_eq!(f.iter().filter(|w| w[0] == ('y', 1.0)).count(), 2);
    assert_eq!(f.iter().filter(|w| w[0] == ('z', 1.0)).count(), 1);
    assert_eq!(f.last().unwrap(), &vec![('m', 2.0)]);
}

#[test]
fn what_depends_on_the_machine_is_refused_naming_the_line() {
    let cases = [
        ("g0 x#5420\n", 1, "system parameter"),
        ("g0 x0\n#<a>=#<_x>\n", 2, "predefined"),
        ("g38.2 z-5 f100\n", 1, "probes"),
        ("m66 p0 l3 q5\n", 1, "waits on an input"),
        ("o<ext> call\n", 1, "not defined above"),
        ("g0 x#31\n", 1, "#31 is read before"),
        (
            "o1 sub\n g0 x#2\no1 endsub\no1 call [1]\n",
            2,
            "neither one of its arguments",
        ),
        ("/g0 x1\n", 1, "block delete"),
        ("g0 x1\ng83 x1 y1 z-1 r1 q1 f100\n", 2, "G83"),
        ("o1 while [1]\no1 endwhile\n", 1, "does not end"),
        ("g2 x10 y0.1 i5 j0 f100\n", 1, "spiral"),
        ("g1 x1 a5 f100\n", 1, "other axes"),
    ];
    for (text, line, want) in cases {
        let e = refused(text);
        assert_eq!(e.line, line, "{text}: {e}");
        assert!(e.to_string().contains(want), "{text}: {e}");
    }
}

#[test]
fn offsets_units_and_g92_give_machine_positions() {
    let mut start = Start::default();
    start.work_offsets[1] = [10.0, 20.0, 0.0];
    let steps = interpret(
        "g55 g20 g0 x1 y1\ng92 x0\ng91 g1 x1 f10\ng92.1\ng90 g0 x0\n",
        &start,
        Bounds::default(),
    )
    .unwrap();
    let tos: Vec<Xyz> = steps
        .iter()
        .flat_map(|s| s.actions.iter())
        .filter_map(|a| match a {
            Action::Rapid { to } | Action::Linear { to, .. } => Some(*to),
            _ => None,
        })
        .collect();
    assert_eq!(tos[0], [35.4, 45.4, 0.0]);
    assert!((tos[1][0] - 60.8).abs() < 1e-12);
    assert_eq!(tos[2][0], 10.0);
}

#[test]
fn r_arcs_and_absolute_centres() {
    // A quarter circle of radius 10 from (0,0) to (10,10), clockwise (the short way):
    // centre (10,0).
    let a = moves("g0 x0 y0\ng2 x10 y10 r10 f100\n");
    let Action::Arc { centre, .. } = a[1] else {
        panic!("{a:?}")
    };
    assert!(
        (centre[0] - 10.0).abs() < 1e-12 && centre[1].abs() < 1e-12,
        "{centre:?}"
    );
    // Negative R: the long way round, the other centre.
    let a = moves("g0 x0 y0\ng2 x10 y10 r-10 f100\n");
    let Action::Arc { centre, .. } = a[1] else {
        panic!()
    };
    assert!(
        centre[0].abs() < 1e-12 && (centre[1] - 10.0).abs() < 1e-12,
        "{centre:?}"
    );
    let a = moves("g0 x0 y0\ng90.1 g18 g3 x10 z10 i0 k10 f100\n");
    let Action::Arc { centre, plane, .. } = a[1] else {
        panic!()
    };
    assert_eq!((plane, centre), (Plane::Zx, [0.0, 0.0, 10.0]));
}

#[test]
fn canned_cycles_expand_as_linuxcnc_moves() {
    // G98 from Z10: R2, Z-3, two holes in G91 with L2.
    let a = moves("g0 x0 y0 z10\ng91 g98 g81 x5 r-8 z-5 l2 f100\n");
    let tos: Vec<(bool, Xyz)> = a
        .iter()
        .map(|m| match m {
            Action::Rapid { to } => (true, *to),
            Action::Linear { to, .. } => (false, *to),
            _ => unreachable!(),
        })
        .collect();
    assert_eq!(
        tos[1..],
        [
            (true, [5.0, 0.0, 10.0]),
            (true, [5.0, 0.0, 2.0]),
            (false, [5.0, 0.0, -3.0]),
            (true, [5.0, 0.0, 10.0]),
            (true, [10.0, 0.0, 10.0]),
            (true, [10.0, 0.0, 2.0]),
            (false, [10.0, 0.0, -3.0]),
            (true, [10.0, 0.0, 10.0]),
        ]
    );
}

#[test]
fn a_parameter_file_gives_the_offsets() {
    let s = read_var_file("5210\t1\n5211 1.5\n5220 2\n5241 10\n5242 -3\n").unwrap();
    assert_eq!(s.system, 1);
    assert_eq!(s.work_offsets[1], [10.0, -3.0, 0.0]);
    assert_eq!(s.g92, [1.5, 0.0, 0.0]);
    assert!(read_var_file("5250 30\n")
        .unwrap_err()
        .message
        .contains("rotated"));
    assert_eq!(read_var_file("5220\n").unwrap_err().line, 1);
}
