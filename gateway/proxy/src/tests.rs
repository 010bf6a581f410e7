use super::*;
use rewrite::{Approach, Compensation, Options, Pose, Rewriter, N_AXIS};
use std::path::Path;

/// The tool lands 10 um short in X and 0.1 % long in Y: the command for nominal p is
/// (p.x + 0.010, p.y / 1.001); known inside 0..300 mm.
struct Skewed;

impl Compensation for Skewed {
    fn describe(&self) -> String {
        "skewed".into()
    }
    fn axes(&self) -> &[usize] {
        &[0, 1]
    }
    fn command_for(&self, p: &Pose, _: &[Approach; N_AXIS]) -> Result<Pose, String> {
        if !(0.0..=300.0).contains(&p[0]) || !(0.0..=300.0).contains(&p[1]) {
            return Err(format!("X{:.3} Y{:.3} is outside the map", p[0], p[1]));
        }
        Ok([p[0] + 0.010, p[1] / 1.001, p[2]])
    }
    fn tool_for(&self, c: &Pose, _: &[Approach; N_AXIS]) -> Result<Pose, String> {
        Ok([c[0] - 0.010, c[1] * 1.001, c[2]])
    }
}

fn started(comp: &Skewed) -> Proxy<'_> {
    let rewriter = Rewriter::new(comp, Options::default()).unwrap();
    let mut p = Proxy::new(rewriter, comp);
    p.start();
    assert_eq!(p.take_to_controller(), b"$#\n$G\n?");
    p.from_controller(
        b"[G54:0.000,0.000,0.000]\r\n[G55:5.000,0.000,0.000]\r\n[G28:0.000,0.000,0.000]\r\nok\r\n\
          [GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]\r\nok\r\n\
          <Idle|MPos:10.010,9.990,0.000|FS:0,0>\r\n",
        0.0,
    );
    p
}

fn text(b: Vec<u8>) -> String {
    String::from_utf8(b).unwrap()
}

#[test]
fn own_queries_are_not_passed_on_and_the_status_shows_the_programmed_position() {
    let comp = Skewed;
    let mut p = started(&comp);
    // None of the gateway's own answers reach the sender: GRBL reports only when asked.
    assert_eq!(text(p.take_to_sender()), "");
    assert!(p.rewriter().position_known());
    // The sender's `?` goes on at once; its report comes back in programmed coordinates.
    p.from_sender(b"?", 0.5);
    assert_eq!(p.take_to_controller(), b"?");
    p.from_controller(b"<Idle|MPos:10.010,9.990,0.000|FS:0,0>\r\n", 0.6);
    assert_eq!(
        text(p.take_to_sender()),
        "<Idle|MPos:10.000,10.000,0.000|FS:0,0>\r\n"
    );
    // A report of the gateway's own poll afterwards is not passed on.
    p.from_controller(b"<Idle|MPos:10.010,9.990,0.000|FS:0,0>\r\n", 0.7);
    assert_eq!(text(p.take_to_sender()), "");
}

#[test]
fn a_split_line_is_answered_once_after_its_last_piece() {
    let comp = Skewed;
    let mut p = started(&comp);
    p.take_to_sender();
    p.from_sender(b"G1 X20 Y10 F600\nG0 X0 Y0\n", 1.0);
    let sent = text(p.take_to_controller());
    let pieces: Vec<&str> = sent.lines().collect();
    assert!(pieces.len() >= 2, "{sent}");
    assert_eq!(pieces[0], "G1 X20.0100 Y9.9900 F600");
    // Nothing answered yet.
    assert!(p.take_to_sender().is_empty());
    // The controller acknowledges all but the last piece: still no answer.
    for _ in 0..pieces.len() - 1 {
        p.from_controller(b"ok\r\n", 1.1);
    }
    assert_eq!(text(p.take_to_sender()), "ok\r\n", "the first line is done");
    p.from_controller(b"ok\r\n", 1.2);
    assert_eq!(text(p.take_to_sender()), "ok\r\n");
    assert_eq!(p.account().acknowledged, vec![1, 2]);
}

#[test]
fn the_controller_buffer_is_never_overfilled() {
    let comp = Skewed;
    let mut p = started(&comp);
    let mut program = String::new();
    for k in 0..40 {
        program.push_str(&format!("G1 X{}.123456 Y{}.654321 F900\n", 10 + k, 20 + k));
    }
    p.from_sender(program.as_bytes(), 1.0);
    let sent = text(p.take_to_controller());
    let bytes: usize = sent.lines().map(|l| l.len() + 1).sum();
    assert!(bytes <= RX_BUFFER, "{bytes} bytes in flight");
    // Each ok lets more through, still within the buffer.
    let mut in_flight: Vec<usize> = sent.lines().map(|l| l.len() + 1).collect();
    for _ in 0..30 {
        p.from_controller(b"ok\r\n", 2.0);
        in_flight.remove(0);
        let more = text(p.take_to_controller());
        in_flight.extend(more.lines().map(|l| l.len() + 1));
        assert!(in_flight.iter().sum::<usize>() <= RX_BUFFER);
    }
}

#[test]
fn a_refused_line_is_not_sent_and_is_answered_in_its_turn() {
    let comp = Skewed;
    let mut p = started(&comp);
    p.take_to_sender();
    p.from_sender(b"G0 X20 Y20\nG0 X400 Y20\nG0 X30 Y30\n", 1.0);
    let sent = text(p.take_to_controller());
    assert!(!sent.contains("X400"), "{sent}");
    assert_eq!(sent.lines().count(), 2, "{sent}");
    // Line 2's refusal waits for line 1's ok.
    let early = text(p.take_to_sender());
    assert!(early.starts_with("[MSG:gateway: line 2:"), "{early}");
    assert!(!early.contains("error"), "{early}");
    p.from_controller(b"ok\r\nok\r\n", 1.1);
    assert_eq!(text(p.take_to_sender()), "ok\r\nerror:33\r\nok\r\n");
    let a = p.account();
    assert_eq!((a.acknowledged, a.refused), (vec![1, 3], vec![2]));
}

#[test]
fn a_controller_error_is_relayed_against_the_senders_line() {
    let comp = Skewed;
    let mut p = started(&comp);
    p.take_to_sender();
    p.from_sender(b"G0 X20 Y20\nM3 S100\n", 1.0);
    p.take_to_controller();
    p.from_controller(b"ok\r\nerror:5\r\n", 1.1);
    assert_eq!(text(p.take_to_sender()), "ok\r\nerror:5\r\n");
}

#[test]
fn realtime_bytes_pass_at_once_and_a_reset_drops_what_was_pending() {
    let comp = Skewed;
    let mut p = started(&comp);
    p.take_to_sender();
    p.from_sender(b"G1 X20 Y20 F100\n!~?", 1.0);
    // Real-time bytes go at once, ahead of pieces still to be written.
    let sent = text(p.take_to_controller());
    assert!(sent.starts_with("!~?G1 X20.0100"), "{sent:?}");
    p.from_sender(&[0x18], 1.1);
    assert_eq!(p.take_to_controller(), vec![0x18]);
    p.from_controller(b"\r\nGrbl 1.1h ['$' for help]\r\n", 1.2);
    assert_eq!(text(p.take_to_sender()), "Grbl 1.1h ['$' for help]\r\n");
    assert!(!p.busy());
    // After the reset the position is asked again before the next move is rewritten.
    p.from_sender(b"G0 X1 Y1\n", 1.3);
    assert_eq!(p.take_to_controller(), b"?");
    p.from_controller(b"<Idle|MPos:20.010,19.980,0.000|FS:0,0>\r\n", 1.4);
    assert!(text(p.take_to_controller()).starts_with("G0 X1.0100"));
}

#[test]
fn a_lost_sender_holds_the_motion_and_says_which_lines_ran() {
    let comp = Skewed;
    let mut p = started(&comp);
    let mut program = String::new();
    for k in 0..20 {
        program.push_str(&format!("G1 X{} Y10 F900\n", 10 + k));
    }
    p.from_sender(program.as_bytes(), 1.0);
    p.take_to_controller();
    p.from_controller(b"ok\r\nok\r\nok\r\n", 1.1);
    p.take_to_controller();
    let a = p.sender_lost();
    assert_eq!(p.take_to_controller(), b"!");
    assert_eq!(a.acknowledged, vec![1, 2, 3]);
    assert!(!a.in_controller.is_empty());
    let all: usize = a.acknowledged.len() + a.in_controller.len() + a.not_sent.len();
    assert_eq!(all, 20, "{a:?}");
}

#[test]
fn a_lost_controller_alarms_the_sender_and_nothing_is_resent() {
    let comp = Skewed;
    let mut p = started(&comp);
    p.take_to_sender();
    p.from_sender(b"G0 X20 Y20\nG0 X21 Y20\n", 1.0);
    p.take_to_controller();
    p.from_controller(b"ok\r\n", 1.1);
    let a = p.controller_lost("the port closed");
    assert_eq!(a.acknowledged, vec![1]);
    assert_eq!(a.in_controller, vec![2]);
    let told = text(p.take_to_sender());
    assert!(
        told.contains("controller lost") && told.contains("ALARM:3"),
        "{told}"
    );
    assert!(told.ends_with("error:9\r\n"), "{told}");
    p.from_sender(b"G0 X1 Y1\n", 1.2);
    assert!(p.take_to_controller().is_empty());
    assert_eq!(text(p.take_to_sender()), "error:9\r\n");
}

#[test]
fn idle_while_lines_wait_counts_as_starvation() {
    let comp = Skewed;
    let mut p = started(&comp);
    p.from_sender(b"G1 X20 Y20 F100\n", 1.0);
    p.take_to_controller();
    p.from_controller(b"<Run|MPos:10.010,9.990,0.000|FS:100,0>\r\n", 1.1);
    assert_eq!(p.stats().starvation_events, 0);
    p.from_controller(b"<Idle|MPos:10.010,9.990,0.000|FS:0,0>\r\n", 1.2);
    p.from_controller(b"<Idle|MPos:10.010,9.990,0.000|FS:0,0>\r\n", 1.3);
    assert_eq!(
        p.stats().starvation_events,
        1,
        "one event, not one per report"
    );
}

/// grblHAL's answers to the gateway's `$#` (six axes), `$G` and `?`.
const GRBLHAL_START: &[u8] =
    b"[G54:0.000,0.000,0.000,0.000,0.000,0.000]\r\n[G55:0.000,0.000,0.000,0.000,0.000,0.000]\r\n\
[G56:0.000,0.000,0.000,0.000,0.000,0.000]\r\n[G57:0.000,0.000,0.000,0.000,0.000,0.000]\r\n\
[G58:0.000,0.000,0.000,0.000,0.000,0.000]\r\n[G59:0.000,0.000,0.000,0.000,0.000,0.000]\r\n\
[G59.1:0.000,0.000,0.000,0.000,0.000,0.000]\r\n[G59.2:0.000,0.000,0.000,0.000,0.000,0.000]\r\n\
[G59.3:0.000,0.000,0.000,0.000,0.000,0.000]\r\n[G28:0.000,0.000,0.000,0.000,0.000,0.000]\r\n\
[G30:0.000,0.000,0.000,0.000,0.000,0.000]\r\n[G92:0.000,0.000,0.000,0.000,0.000,0.000]\r\n\
[T:1|0.000,0.000,0.000,0.000,0.000,0.000|0.000|6,0,0|]\r\n[G51:1.000,1.000,1.000]\r\n\
[TLO:0.000,0.000,0.000,0.000,0.000,0.000]\r\n[TLR:0]\r\n[HOME:0.000,0.000,0.000:0]\r\n\
[PRB:0.000,0.000,0.000,0.000,0.000,0.000:0]\r\nok\r\n\
[GC:G0 G54 G17 G21 G90 G94 G40 G49 G98 G50 M5 M9 T0 F0 S0.]\r\nok\r\n\
<Idle|MPos:10.010,9.990,0.000,0.000,0.000,0.000|Bf:100,1023|FS:0,0|Ov:100,100,100|A:|TLR:0>\r\n";

#[test]
fn none_of_grblhals_answers_to_the_gateways_own_queries_reach_the_sender() {
    let comp = Skewed;
    let rewriter = Rewriter::new(&comp, Options::default()).unwrap();
    let mut p = Proxy::new(rewriter, &comp);
    p.start();
    p.take_to_controller();
    p.from_controller(GRBLHAL_START, 0.0);
    assert_eq!(text(p.take_to_sender()), "");
    assert!(p.rewriter().position_known());
    // The sender's own `$#` gets every line.
    p.from_sender(b"$#\n", 1.0);
    assert_eq!(p.take_to_controller(), b"$#\n");
    let own = &GRBLHAL_START[..GRBLHAL_START
        .windows(4)
        .position(|w| w == b"ok\r\n")
        .unwrap()
        + 4];
    p.from_controller(own, 1.1);
    assert_eq!(text(p.take_to_sender()), text(own.to_vec()));
}

#[test]
fn one_time_report_fields_taken_by_the_gateways_polls_reach_the_sender_once() {
    let comp = Skewed;
    let mut p = started(&comp);
    p.take_to_sender();
    // The gateway's own poll gets the report right after an override and an offset
    // change: GRBL prints Ov:, A: and WCO: there and not in the next reports.
    p.from_controller(
        b"<Idle|MPos:10.010,9.990,0.000|FS:0,0|WCO:1.000,2.000,0.000|Ov:120,100,100|A:SF>\r\n",
        1.0,
    );
    assert_eq!(text(p.take_to_sender()), "");
    p.from_sender(b"?", 1.1);
    p.from_controller(b"<Idle|MPos:10.010,9.990,0.000|FS:0,0>\r\n", 1.2);
    assert_eq!(
        text(p.take_to_sender()),
        "<Idle|MPos:10.000,10.000,0.000|FS:0,0|WCO:1.000,2.000,0.000|Ov:120,100,100|A:SF>\r\n"
    );
    // Delivered once: the next report is as GRBL sent it.
    p.from_sender(b"?", 1.3);
    p.from_controller(b"<Idle|MPos:10.010,9.990,0.000|FS:0,0>\r\n", 1.4);
    assert_eq!(
        text(p.take_to_sender()),
        "<Idle|MPos:10.000,10.000,0.000|FS:0,0>\r\n"
    );
    // A fresher field in the sender's report wins; `Ov:` without `A:` (GRBL: all
    // accessories off) is not given an older `A:`.
    p.from_controller(
        b"<Idle|MPos:10.010,9.990,0.000|FS:0,0|Ov:120,100,100|A:S>\r\n",
        1.5,
    );
    p.from_sender(b"?", 1.6);
    p.from_controller(
        b"<Idle|MPos:10.010,9.990,0.000|FS:0,0|Ov:100,100,100>\r\n",
        1.7,
    );
    assert_eq!(
        text(p.take_to_sender()),
        "<Idle|MPos:10.000,10.000,0.000|FS:0,0|Ov:100,100,100>\r\n"
    );
    // grblHAL: `A:` alone and its change-only fields.
    p.from_controller(
        b"<Idle|MPos:10.010,9.990,0.000|FS:0,0|A:M|H:1|TLR:1>\r\n",
        1.8,
    );
    p.from_sender(b"?", 1.9);
    p.from_controller(b"<Idle|MPos:10.010,9.990,0.000|FS:0,0|H:0>\r\n", 2.0);
    assert_eq!(
        text(p.take_to_sender()),
        "<Idle|MPos:10.000,10.000,0.000|FS:0,0|H:0|A:M|TLR:1>\r\n"
    );
}

#[test]
fn a_line_longer_than_grbls_buffer_is_refused_with_error_11_and_not_held() {
    let comp = Skewed;
    let mut p = started(&comp);
    p.take_to_sender();
    // 50 MiB without a line end, in the pieces a pty delivers.
    let chunk = vec![b'X'; 4096];
    for k in 0..(50 << 20) / chunk.len() {
        p.from_sender(&chunk, 1.0 + k as f64 * 1e-6);
        assert!(p.held_bytes() <= RAW_LINE_KEPT + 80, "{}", p.held_bytes());
    }
    p.from_sender(b"\nG0 X20 Y20\n", 2.0);
    let told = text(p.take_to_sender());
    assert!(
        told.len() < 300,
        "no echo of the line: {} bytes",
        told.len()
    );
    assert!(told.contains("longer than GRBL's line buffer"), "{told}");
    assert!(told.ends_with("error:11\r\n"), "{told}");
    // Only the next line went to the controller.
    let sent = text(p.take_to_controller());
    assert!(
        sent.starts_with("G0 X20.0100") && !sent.contains("XXX"),
        "{sent}"
    );
    // GRBL counts what is left without spaces and comments: 80 characters overflow,
    // 79 do not, and a long comment does not count.
    p.from_controller(b"ok\r\n", 2.1);
    p.take_to_sender();
    let long = format!("G4P0{}\n", "0".repeat(76));
    p.from_sender(long.as_bytes(), 2.2);
    assert!(p.take_to_controller().is_empty());
    assert!(text(p.take_to_sender()).ends_with("error:11\r\n"));
    let just = format!("G4 P0{}\n", "0".repeat(75));
    p.from_sender(just.as_bytes(), 2.3);
    assert_eq!(text(p.take_to_controller()), just);
    p.from_controller(b"ok\r\n", 2.4);
    assert_eq!(text(p.take_to_sender()), "ok\r\n");
    let commented = format!("G4 P0 ({})\n", "a comment ".repeat(1000));
    p.from_sender(commented.as_bytes(), 2.5);
    assert_eq!(
        text(p.take_to_controller()),
        "G4P0\n",
        "kept as GRBL keeps it"
    );
    p.from_controller(b"ok\r\n", 2.6);
    assert_eq!(text(p.take_to_sender()), "ok\r\n");
}

#[test]
fn a_percent_line_is_answered_error_1_as_grbl_does_and_not_sent() {
    let comp = Skewed;
    let mut p = started(&comp);
    p.take_to_sender();
    p.from_sender(b"%\nG0 X20 Y20\n% end\n", 1.0);
    let sent = text(p.take_to_controller());
    assert!(!sent.contains('%'), "{sent}");
    p.from_controller(b"ok\r\n", 1.1);
    let told = text(p.take_to_sender());
    let answers: Vec<&str> = told.lines().filter(|l| !l.starts_with("[MSG:")).collect();
    assert_eq!(answers, ["error:1", "ok", "error:1"], "{told}");
    assert_eq!(p.account().refused, vec![1, 3]);
}

/// GRBL's filter drops spaces inside a number, an unclosed `(` and a `/` anywhere
/// (issue 38, checked on the firmware): the gateway takes these lines as GRBL does and
/// sends the compensated moves, each answered `ok`.
#[test]
fn lines_grbls_filter_accepts_are_compensated_as_grbl_reads_them() {
    let comp = Skewed;
    let mut p = started(&comp);
    p.take_to_sender();
    p.from_sender(
        b"G0 X2 0 Y2 0\nG0 X30 (an unclosed comment Y90\nG0 X40 / Y50\n",
        1.0,
    );
    let sent = text(p.take_to_controller());
    let targets: Vec<(f64, f64)> = sent
        .lines()
        .map(|l| {
            let mut interp = protocol::grbl::gcode::Interpreter::new();
            let f = protocol::grbl::gcode::filter_line(l).unwrap();
            interp.execute(&f, false).unwrap();
            (interp.position[0], interp.position[1])
        })
        .collect();
    let wanted = [
        (20.010, 20.0 / 1.001),
        (30.010, 20.0 / 1.001),
        (40.010, 50.0 / 1.001),
    ];
    assert_eq!(targets.len(), 3, "{sent}");
    for ((x, y), (wx, wy)) in targets.iter().zip(wanted) {
        assert!((x - wx).abs() < 1e-4 && (y - wy).abs() < 1e-4, "{sent}");
    }
    p.from_controller(b"ok\r\nok\r\nok\r\n", 1.1);
    assert_eq!(text(p.take_to_sender()), "ok\r\nok\r\nok\r\n");
    assert!(p.account().refused.is_empty());
}

#[test]
fn a_sender_that_ignores_the_buffer_is_not_read_past_a_bound() {
    let comp = Skewed;
    let mut p = started(&comp);
    let mut k = 0;
    while p.accepts_sender_bytes() {
        p.from_sender(format!("G1 X{} Y10 F900\n", 10 + k % 100).as_bytes(), 1.0);
        k += 1;
        assert!(k <= MAX_UNANSWERED_LINES, "never stops");
    }
    assert_eq!(k, MAX_UNANSWERED_LINES);
    // Answers from the controller make room again.
    p.take_to_controller();
    p.from_controller(b"ok\r\n", 2.0);
    assert!(p.accepts_sender_bytes());
}

#[tokio::test]
async fn the_senders_link_never_replaces_or_deletes_anything_but_its_own_symlink() {
    let dir = std::env::temp_dir().join(format!("proxy-link-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // A regular file where the link should go: refused, left as it was.
    let file = dir.join("program.nc");
    std::fs::write(&file, "G0 X1\n").unwrap();
    let e = crate::SenderPort::create(Some(&file))
        .err()
        .expect("refused");
    assert!(e.to_string().contains("not a symlink"), "{e}");
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "G0 X1\n");
    // An old symlink is replaced; the link goes with the port...
    let link = dir.join("ttyGATEWAY");
    let _ = std::fs::remove_file(&link);
    std::os::unix::fs::symlink("/dev/null", &link).unwrap();
    let port = crate::SenderPort::create(Some(&link)).unwrap();
    assert_eq!(std::fs::read_link(&link).unwrap(), Path::new(port.path()));
    drop(port);
    assert!(link.symlink_metadata().is_err());
    // ... unless something else took its place meanwhile.
    let port = crate::SenderPort::create(Some(&link)).unwrap();
    std::fs::remove_file(&link).unwrap();
    std::fs::write(&link, "mine").unwrap();
    drop(port);
    assert_eq!(std::fs::read_to_string(&link).unwrap(), "mine");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_greeting_comes_before_the_first_g_code_lines_answer_and_once() {
    let comp = Skewed;
    let mut p = started(&comp);
    p.take_to_sender();
    p.greet("map v1, reference #2 [3 min old]\nx");
    // A `$` line's answer (a listing a strict sender parses) gets no message.
    p.from_sender(b"$I\n", 1.0);
    p.take_to_controller();
    p.from_controller(b"[VER:1.1h.20190825:]\r\nok\r\n", 1.1);
    assert_eq!(text(p.take_to_sender()), "[VER:1.1h.20190825:]\r\nok\r\n");
    p.from_sender(b"G0 X1 Y1\nG0 X2 Y2\n", 1.2);
    assert_eq!(
        text(p.take_to_sender()),
        "[MSG:gateway: map v1, reference #2 (3 min old) x]\r\n"
    );
    p.take_to_controller();
    p.from_controller(b"ok\r\nok\r\n", 1.3);
    assert_eq!(text(p.take_to_sender()), "ok\r\nok\r\n");
}

#[test]
fn after_the_senders_homing_the_gateway_references_before_the_next_line() {
    let comp = Skewed;
    let seen = std::cell::RefCell::new(Vec::new());
    let mut p = started(&comp);
    p.take_to_sender();
    p.after_homing(AfterHoming::Reference(Rereference {
        points_mm: vec![[100.0, 80.0]],
        approach_mm: 0.05,
        arrivals: 1,
        in_use: None,
        hook: Box::new(|s| {
            seen.borrow_mut().push(s.to_vec());
            Ok("zero moved (+6.70, -8.29) um".into())
        }),
    }));
    // The greeting of the map as it was, not shown yet when the homing comes first.
    p.greet("map v1, no reference recorded");
    p.from_sender(b"$H\nG1 X20 Y10 F600\n", 1.0);
    assert_eq!(text(p.take_to_controller()), "$H\n");
    p.from_controller(b"ok\r\n", 2.0);
    let told = text(p.take_to_sender());
    assert!(told.starts_with("ok\r\n[MSG:gateway: homed: "), "{told}");
    // Where the homing left the machine, then to the reference point from below.
    assert_eq!(text(p.take_to_controller()), "?");
    p.from_controller(b"<Idle|MPos:10.010,9.990,0.000|FS:0,0>\r\n", 2.1);
    // The controller's modal state first (to set its motion mode again afterwards).
    modal(&mut p, "G0", 2.15);
    assert_eq!(
        text(p.take_to_controller()),
        "G53G0X99.9500Y79.9500\nG53G0X100.0000Y80.0000\nG4P0\n"
    );
    assert_eq!(p.frame_due(), None);
    p.from_controller(b"ok\r\nok\r\n", 2.2);
    assert_eq!(p.frame_due(), None);
    p.from_controller(b"ok\r\n", 2.3);
    assert_eq!(
        p.frame_due(),
        Some([100.0, 80.0]),
        "at rest at the reference point"
    );
    // The sender's next line waits meanwhile.
    assert!(p.take_to_controller().is_empty());
    p.frame_measured(Ok([6.7, -8.29]));
    assert_eq!(*seen.borrow(), vec![vec![[6.7, -8.29]]]);
    let told = text(p.take_to_sender());
    assert!(
        told.contains("[MSG:gateway: referenced: zero moved"),
        "{told}"
    );
    // Back, the sender's motion mode (G1 from its $G at the start was G0: none), dwell.
    assert_eq!(text(p.take_to_controller()), "G53G0X10.0100Y9.9900\nG4P0\n");
    p.from_controller(b"ok\r\nok\r\n", 2.4);
    // The position is learnt again, then the line goes.
    assert_eq!(text(p.take_to_controller()), "?");
    p.from_controller(b"<Idle|MPos:10.010,9.990,0.000|FS:0,0>\r\n", 2.5);
    let sent = text(p.take_to_controller());
    assert!(sent.starts_with("G1 X20.0100 Y9.9900 F600"), "{sent}");
    // Issue 38: the stale greeting ("no reference recorded") no longer follows the
    // reference.
    let told = text(p.take_to_sender());
    assert!(!told.contains("no reference recorded"), "{told}");
}

#[test]
fn without_a_camera_motion_after_homing_is_refused_until_referenced() {
    let comp = Skewed;
    let mut p = started(&comp);
    p.take_to_sender();
    p.after_homing(AfterHoming::Refuse);
    p.from_sender(b"$H\n", 1.0);
    p.take_to_controller();
    p.from_controller(b"ok\r\n", 2.0);
    let told = text(p.take_to_sender());
    assert!(told.contains("motion is refused (error:9)"), "{told}");
    p.from_sender(b"G0 X1 Y1\n$G\n", 2.1);
    // The move waits for the position, then is refused; `$G` goes through.
    let out = text(p.take_to_controller());
    if out == "?" {
        p.from_controller(b"<Idle|MPos:10.010,9.990,0.000|FS:0,0>\r\n", 2.2);
    }
    let told = text(p.take_to_sender());
    assert!(
        told.contains("not referenced again") && told.ends_with("error:9\r\n"),
        "{told}"
    );
    assert_eq!(text(p.take_to_controller()), "$G\n");
    p.from_controller(b"[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]\r\nok\r\n", 2.3);
    assert!(text(p.take_to_sender()).ends_with("ok\r\n"));
    p.referenced("reference #3");
    p.from_sender(b"G0 X1 Y1\n", 2.4);
    let sent = text(p.take_to_controller());
    assert!(sent.starts_with("G0 X1.0100"), "{sent}");
}

/// A re-reference with the scale points, two arrivals at each, in use every 300 s with
/// the tool clear at machine Z >= -5.
fn in_use_plan<'a>(seen: &'a std::cell::RefCell<Vec<Vec<[f64; 2]>>>) -> AfterHoming<'a> {
    AfterHoming::Reference(Rereference {
        points_mm: vec![[100.0, 80.0], [180.0, 80.0], [100.0, 140.0]],
        approach_mm: 0.05,
        arrivals: 2,
        in_use: Some(InUse {
            every_s: 300.0,
            clear_z_mm: -5.0,
            first_due_s: 300.0,
        }),
        hook: Box::new(|s| {
            seen.borrow_mut().push(s.to_vec());
            Ok("shift and scale".into())
        }),
    })
}

/// A pass-through with [`in_use_plan`] at 300 s of its clock: it asks where the machine
/// is, and hears that it is idle at X20.010 Y9.990 Z0 (the tool clear).
fn due_at_rest<'a>(
    comp: &'a Skewed,
    seen: &'a std::cell::RefCell<Vec<Vec<[f64; 2]>>>,
) -> Proxy<'a> {
    let mut p = started(comp);
    p.take_to_sender();
    p.after_homing(in_use_plan(seen));
    p.tick(300.0);
    assert_eq!(text(p.take_to_controller()), "?");
    p.from_controller(b"<Idle|MPos:20.010,9.990,0.000|FS:0,0>\r\n", 300.1);
    p
}

/// Answers the re-reference's own `$G` with the controller's motion mode `motion`.
fn modal(p: &mut Proxy<'_>, motion: &str, now_s: f64) {
    assert_eq!(text(p.take_to_controller()), "$G\n");
    let reply = format!("[GC:{motion} G54 G17 G21 G90 G94 M5 M9 T0 F600 S0]\r\nok\r\n");
    p.from_controller(reply.as_bytes(), now_s);
}

/// Answers the gateway's own lines of one arrival (two moves and a dwell) and returns
/// where the frame is due.
fn arrive(p: &mut Proxy<'_>, expect: &str, now_s: f64) -> Option<[f64; 2]> {
    assert_eq!(text(p.take_to_controller()), expect);
    assert_eq!(p.frame_due(), None);
    p.from_controller(b"ok\r\nok\r\nok\r\n", now_s);
    p.frame_due()
}

#[test]
fn in_use_the_gateway_re_references_with_the_scale_points_when_due_idle_and_clear() {
    let comp = Skewed;
    let seen = std::cell::RefCell::new(Vec::new());
    let mut p = started(&comp);
    p.take_to_sender();
    p.after_homing(in_use_plan(&seen));
    // Not due yet: nothing of the gateway's.
    p.tick(299.0);
    assert!(p.take_to_controller().is_empty());
    // Due, but the sender's line is on its way: it waits.
    p.from_sender(b"G1 X20 Y10 F600\n", 300.0);
    assert!(text(p.take_to_controller()).starts_with("G1 X20.0100"));
    p.tick(300.2);
    assert!(
        p.take_to_controller().is_empty(),
        "not while a line is owed"
    );
    p.from_controller(b"ok\r\n", 300.3);
    assert_eq!(text(p.take_to_sender()), "ok\r\n");
    // Quiet: where is the machine? Idle, but the tool is down (Z -12): it waits, says so
    // once.
    p.tick(300.4);
    assert_eq!(text(p.take_to_controller()), "?");
    p.from_controller(b"<Idle|MPos:20.010,9.990,-12.000|FS:0,0>\r\n", 300.5);
    let told = text(p.take_to_sender());
    assert!(
        told.contains("it waits for the tool at or above machine Z -5.000 (now -12.000)"),
        "{told}"
    );
    assert!(
        p.take_to_controller().is_empty(),
        "no motion with the tool down"
    );
    p.tick(300.6);
    assert_eq!(text(p.take_to_controller()), "?");
    p.from_controller(b"<Run|MPos:20.010,9.990,-8.000|FS:600,0>\r\n", 300.7);
    assert!(p.take_to_controller().is_empty(), "not while it moves");
    assert!(p.take_to_sender().is_empty(), "said once");
    // The tool is up and the machine idle: the reference point, then each scale point,
    // two arrivals each from below, XY only.
    p.tick(300.8);
    assert_eq!(text(p.take_to_controller()), "?");
    p.from_controller(b"<Idle|MPos:20.010,9.990,-2.000|FS:0,0>\r\n", 300.9);
    // The controller's motion mode now: the sender's G1.
    modal(&mut p, "G1", 300.95);
    let told = text(p.take_to_sender());
    assert!(
        told.contains("re-referencing in use (every 300 s)"),
        "{told}"
    );
    // The sender's line meanwhile waits (a modal G1 from its line before).
    p.from_sender(b"X30 Y10\n", 301.0);
    let mut frames = Vec::new();
    for (point, at) in [[100.0, 80.0], [180.0, 80.0], [100.0, 140.0]]
        .iter()
        .enumerate()
    {
        for _ in 0..2 {
            let expect = format!(
                "G53G0X{:.4}Y{:.4}\nG53G0X{:.4}Y{:.4}\nG4P0\n",
                at[0] - 0.05,
                at[1] - 0.05,
                at[0],
                at[1]
            );
            assert_eq!(arrive(&mut p, &expect, 302.0), Some(*at));
            frames.push(point);
            p.frame_measured(Ok([point as f64, frames.len() as f64]));
        }
    }
    // The means of each point's two frames, in the plan's order.
    assert_eq!(
        *seen.borrow(),
        vec![vec![[0.0, 1.5], [1.0, 3.5], [2.0, 5.5]]]
    );
    assert!(text(p.take_to_sender()).contains("referenced: shift and scale"));
    // Back to the XY it left (Z never moved) and to G1 again, so that the sender's
    // modal line is a feed move, then the line after the position.
    assert_eq!(
        text(p.take_to_controller()),
        "G53G0X20.0100Y9.9900\nG1\nG4P0\n"
    );
    p.from_controller(b"ok\r\nok\r\nok\r\n", 310.0);
    assert_eq!(text(p.take_to_controller()), "?");
    p.from_controller(b"<Idle|MPos:20.010,9.990,-2.000|FS:0,0>\r\n", 310.1);
    assert_eq!(text(p.take_to_controller()), "X30.0100 Y9.9900\n");
    p.from_controller(b"ok\r\n", 310.2);
    assert_eq!(text(p.take_to_sender()), "ok\r\n");
    // The next one is due 300 s after this one ended.
    p.tick(609.0);
    assert!(p.take_to_controller().is_empty());
    p.tick(610.1);
    assert_eq!(text(p.take_to_controller()), "?");
}

#[test]
fn a_failed_frame_in_use_keeps_the_last_reference_and_returns_but_after_homing_locks() {
    let comp = Skewed;
    let seen = std::cell::RefCell::new(Vec::new());
    let mut p = due_at_rest(&comp, &seen);
    modal(&mut p, "G0", 300.15);
    p.take_to_sender();
    let first = "G53G0X99.9500Y79.9500\nG53G0X100.0000Y80.0000\nG4P0\n";
    assert_eq!(arrive(&mut p, first, 300.2), Some([100.0, 80.0]));
    p.frame_measured(Err("no dots in the frame".into()));
    let told = text(p.take_to_sender());
    assert!(
        told.contains("the re-reference in use failed: no dots in the frame; the map keeps its last reference"),
        "{told}"
    );
    assert!(seen.borrow().is_empty(), "nothing applied");
    assert_eq!(text(p.take_to_controller()), "G53G0X20.0100Y9.9900\nG4P0\n");
    p.from_controller(b"ok\r\nok\r\n", 301.0);
    // Lines go on.
    p.from_sender(b"G1 X30 Y10 F600\n", 301.1);
    assert_eq!(text(p.take_to_controller()), "?");
    p.from_controller(b"<Idle|MPos:20.010,9.990,0.000|FS:0,0>\r\n", 301.2);
    assert!(text(p.take_to_controller()).starts_with("G1 X30.0100"));
    p.from_controller(b"ok\r\n", 301.3);
    assert_eq!(text(p.take_to_sender()), "ok\r\n");
    // After a homing the same failure locks motion out.
    p.from_sender(b"$H\n", 302.0);
    assert_eq!(text(p.take_to_controller()), "$H\n");
    p.from_controller(b"ok\r\n", 303.0);
    let told = text(p.take_to_sender());
    assert!(told.contains("and each axis's scale"), "{told}");
    assert_eq!(text(p.take_to_controller()), "?");
    p.from_controller(b"<Idle|MPos:0.000,0.000,0.000|FS:0,0>\r\n", 303.1);
    modal(&mut p, "G1", 303.15);
    assert_eq!(arrive(&mut p, first, 303.2), Some([100.0, 80.0]));
    p.frame_measured(Err("no dots in the frame".into()));
    assert!(text(p.take_to_sender()).contains("motion is refused until the machine is referenced"));
    p.from_sender(b"G0 X1 Y1\n", 304.0);
    assert!(text(p.take_to_sender()).ends_with("error:9\r\n"));
}

#[test]
fn in_use_the_gateway_waits_while_the_motion_mode_is_one_it_cannot_set_again() {
    let comp = Skewed;
    let seen = std::cell::RefCell::new(Vec::new());
    let mut p = due_at_rest(&comp, &seen);
    // An arc mode: after G0 moves it could not be set again without axis words.
    modal(&mut p, "G2", 300.2);
    let told = text(p.take_to_sender());
    assert!(
        told.contains("it waits for the motion mode G0, G1 or G80 (now G2)"),
        "{told}"
    );
    assert!(p.take_to_controller().is_empty(), "no motion");
    // A second later it asks again, and moves once the mode is one it can set.
    p.tick(300.5);
    assert!(p.take_to_controller().is_empty());
    p.tick(301.3);
    assert_eq!(text(p.take_to_controller()), "?");
    p.from_controller(b"<Idle|MPos:20.010,9.990,0.000|FS:0,0>\r\n", 301.4);
    modal(&mut p, "G80", 301.5);
    assert!(text(p.take_to_sender()).contains("re-referencing in use"));
    let first = "G53G0X99.9500Y79.9500\nG53G0X100.0000Y80.0000\nG4P0\n";
    assert_eq!(arrive(&mut p, first, 301.6), Some([100.0, 80.0]));
}
