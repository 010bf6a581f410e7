//! The RS274/NGC corpus (`tests/ngc`, see its README): every program is either
//! rewritten or refused as its first line says. The rewritten ones are run in the real
//! LinuxCNC by `tests/tests/a_real_linuxcnc.rs`; here each is checked without a controller:
//! the rewrite succeeds, its output is flat (no parameters, no O-words, no arcs, no
//! cycles), and read again it visits the program's end points in order; each refused
//! one is refused naming its line and its construct.

use protocol::ngc::{interpret, read_var_file, Action, Bounds, Start, Xyz};
use rewrite::ngc::{rewrite_ngc, NgcOptions};
use rewrite::Identity;

fn corpus() -> Vec<(String, String)> {
    let dir = system_tests::workspace().join("tests/ngc");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .expect("tests/ngc")
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "ngc"))
        .collect();
    files.sort();
    files
        .into_iter()
        .map(|p| {
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            (name, std::fs::read_to_string(&p).unwrap())
        })
        .collect()
}

/// The parameter file the corpus's LinuxCNC starts with.
pub fn corpus_start() -> Start {
    let var = std::fs::read_to_string(system_tests::workspace().join("tests/ngc/sim.var")).unwrap();
    read_var_file(&var).unwrap()
}

/// The straight-move end points of a program, as the rewrite reads it.
fn ends(text: &str, start: &Start) -> Vec<Xyz> {
    interpret(text, start, Bounds::default())
        .unwrap()
        .into_iter()
        .flat_map(|s| s.actions)
        .filter_map(|a| match a {
            Action::Rapid { to } | Action::Linear { to, .. } | Action::Arc { to, .. } => Some(to),
            _ => None,
        })
        .collect()
}

#[test]
fn every_corpus_program_is_rewritten_or_refused_naming_its_line() {
    let start = corpus_start();
    let mut rewritten = 0;
    let mut refused = 0;
    for (name, text) in corpus() {
        let header = text.lines().next().unwrap();
        let options = NgcOptions {
            start: start.clone(),
            position: Some([5.0, 5.0, 0.0]),
            ..Default::default()
        };
        let result = rewrite_ngc(&text, &Identity, &options);
        if header == "(expect: rewritten)" {
            let (out, report) = result.unwrap_or_else(|e| panic!("{name}: {e}"));
            for construct in ["#", "O", "o", "G2 ", "G3 ", "G8", "[", "G91", "G20"] {
                let body: String = out
                    .lines()
                    .filter(|l| !l.starts_with("G20") && !l.starts_with("G91"))
                    .collect::<Vec<_>>()
                    .join("\n");
                assert!(!body.contains(construct), "{name}: `{construct}` in\n{out}");
            }
            // Each end point of the program is an end point of the rewrite, in order
            // (the rewrite adds the points of its chords and pieces between).
            let mut written = ends(&out, &start).into_iter();
            for p in ends(&text, &start) {
                assert!(
                    written.any(|q| (0..3).all(|k| (q[k] - p[k]).abs() < 1e-6)),
                    "{name}: {p:?} not visited in order"
                );
            }
            eprintln!(
                "{name}: rewritten, {} blocks run, {} lines out",
                report.blocks_run, report.output_lines
            );
            rewritten += 1;
        } else {
            let rest = header
                .strip_prefix("(expect: refused at line ")
                .and_then(|r| r.strip_suffix(')'))
                .unwrap_or_else(|| panic!("{name}: header `{header}`"));
            let (line, want) = rest.split_once(": ").unwrap();
            let e = result
                .err()
                .unwrap_or_else(|| panic!("{name}: rewritten, expected refused"));
            assert_eq!(e.line, line.parse::<usize>().unwrap(), "{name}: {e}");
            assert!(e.to_string().contains(want), "{name}: {e}");
            eprintln!("{name}: refused: {e}");
            refused += 1;
        }
    }
    assert!(
        rewritten >= 4 && refused >= 10,
        "{rewritten} rewritten, {refused} refused"
    );
}
