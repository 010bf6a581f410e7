//! Differential tests: the same bytes through real GRBL 1.1h (gnea/grbl with grbl-sim,
//! built from `../shared/peers` by `tests/firmware/build.sh`) and through our GRBL
//! emulator (`emulators::grbl` on a pseudo-terminal, real-time clock), answers compared
//! line by line. Timing-dependent values (positions and rates while something moves)
//! are normalised; so is the `Pn:` field (the simulator's control and probe pins read
//! constant and show as active; its limits follow the harness's switches). What else
//! differs is listed, with its reason, in docs/grbl-firmware.md.
//!
//! Both controllers get the same settings first (the firmware's `$$`, sent to the
//! emulator), so every case starts from the same state. A missing firmware or socat
//! fails the test, naming the install step.

use emulators::grbl::device::DEFAULT_BUILD_OPTIONS;
use emulators::grbl::{GrblConfig, GrblDevice, GrblPty};
use std::time::{Duration, Instant};
use system_tests::firmware::{Firmware, RunningFirmware, TtyClient};
use world::axes::{AxesMachine, AxesPosition, AxisLimits, SharedAxes, Workpiece};
use world::Clock;

/// Bound of every wait for an answer (it only ends a broken test).
const LIMIT: Duration = Duration::from_secs(30);

/// The emulator's machine for the comparison: three free axes whose probe input reads
/// as the simulator's does (the pin is low: "touching" unless `$6` inverts it), and
/// which never make contact during a probing move.
struct SimPins;

impl Workpiece for SimPins {
    fn axes(&self) -> usize {
        3
    }
    fn limits(&self, _: usize) -> AxisLimits {
        AxisLimits {
            min: -10_000.0,
            max: 10_000.0,
            max_rate: 500.0,
        }
    }
    fn probe_contact(&mut self, _: &AxesPosition, _: &AxesPosition) -> Option<AxesPosition> {
        None
    }
    fn probe_touching(&self, _: &AxesPosition) -> bool {
        true
    }
}

/// The emulator on a pty, served by its own runtime.
struct Emulator {
    pty: Option<GrblPty>,
    rt: tokio::runtime::Runtime,
    _axes: SharedAxes,
}

impl Emulator {
    fn start() -> Emulator {
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .enable_all()
            .build()
            .expect("a tokio runtime");
        let axes = AxesMachine::new(Box::new(SimPins)).shared();
        let dev = GrblDevice::with_axes(
            axes.clone(),
            GrblConfig {
                clock: Clock::Scaled(1.0),
                // GRBL 1.1h's default config.h, as grbl-sim is built.
                build_options: DEFAULT_BUILD_OPTIONS,
                ..Default::default()
            },
        );
        let pty = {
            let _g = rt.enter();
            GrblPty::spawn(dev, None).expect("the emulator's pseudo-terminal")
        };
        Emulator {
            pty: Some(pty),
            rt,
            _axes: axes,
        }
    }

    fn path(&self) -> String {
        self.pty.as_ref().expect("running").path().to_string()
    }
}

impl Drop for Emulator {
    fn drop(&mut self) {
        if let Some(p) = self.pty.take() {
            self.rt.block_on(p.hang_up());
        }
    }
}

/// One exchange's answers, as compared.
struct Case {
    name: String,
    firmware: String,
    emulator: String,
    /// A difference written down in docs/grbl-firmware.md, with its reason.
    known: Option<&'static str>,
}

/// Both controllers, driven in lock step.
struct Pair {
    _fw: RunningFirmware,
    _emu: Emulator,
    f: TtyClient,
    e: TtyClient,
    cases: Vec<Case>,
    /// Whether the one-time report fields (`WCO:`, `Ov:`) are comparable: false after
    /// a settle that polled a different number of times on each side.
    counters_known: bool,
    started: Instant,
}

fn banner(l: &str) -> bool {
    l.starts_with("Grbl 1.1h")
}

fn ends_answer(l: &str) -> bool {
    l == "ok" || l.starts_with("error:")
}

fn is_status(l: &str) -> bool {
    l.starts_with('<') && l.ends_with('>')
}

impl Pair {
    /// Start both; the firmware's first power-up and the emulator's banner are read;
    /// the emulator gets the firmware's settings.
    fn start() -> Pair {
        let started = Instant::now();
        let fw = Firmware::Grbl11h
            .start()
            .unwrap_or_else(|e| panic!("real GRBL 1.1h: {e}"));
        let mut f = fw.open().unwrap_or_else(|e| panic!("{e}"));
        f.read_through_line(LIMIT, |l| l.starts_with("Grbl 1.1h"))
            .expect("the firmware's banner");
        let emu = Emulator::start();
        let mut e = TtyClient::open(std::path::Path::new(&emu.path())).expect("emulator pty");
        e.read_through_line(LIMIT, |l| l.starts_with("Grbl 1.1h"))
            .expect("the emulator's banner");
        let mut pair = Pair {
            _fw: fw,
            _emu: emu,
            f,
            e,
            cases: Vec::new(),
            counters_known: true,
            started,
        };
        let settings = pair.fw_line("$$");
        for l in settings.lines().filter(|l| l.starts_with('$')) {
            e_line(&mut pair.e, l);
        }
        pair
    }

    fn fw_line(&mut self, cmd: &str) -> String {
        self.f.send(format!("{cmd}\n").as_bytes());
        self.f.read_through_line(LIMIT, ends_answer).unwrap()
    }

    /// Send `bytes` to both and read each answer through the line `done` accepts;
    /// recorded as case `name`.
    fn case(&mut self, name: &str, bytes: &[u8], done: impl Fn(&str) -> bool + Copy) {
        self.f.send(bytes);
        self.e.send(bytes);
        let fa = self
            .f
            .read_through_line(LIMIT, done)
            .unwrap_or_else(|e| panic!("{name}: firmware: {e}"));
        let ea = self
            .e
            .read_through_line(LIMIT, done)
            .unwrap_or_else(|e| format!("(no answer: {e})"));
        let keep = self.counters_known;
        self.cases.push(Case {
            name: name.to_string(),
            firmware: normalise(&fa, keep),
            emulator: normalise(&ea, keep),
            known: None,
        });
    }

    /// A line (`\n` added), answered by `ok` or `error:N`.
    fn line(&mut self, cmd: &str) {
        self.case(cmd, format!("{cmd}\n").as_bytes(), ends_answer);
    }

    /// Polls the firmware (unrecorded) until its status starts with `state`: grbl-sim
    /// may answer `ok` to a motion block a moment before its planner starts it. Bounded
    /// by a number of polls, not by time.
    fn firmware_until(&mut self, state: &str) {
        for _ in 0..1000 {
            self.f.send(b"?");
            let report = self.f.read_through_line(LIMIT, is_status).unwrap();
            if report.lines().any(|l| l.starts_with(state)) {
                // The polls took the one-time fields on one side only.
                self.counters_known = false;
                return;
            }
        }
        panic!("the firmware never reported {state}");
    }

    /// A status report.
    fn status(&mut self, name: &str) {
        self.case(name, b"?", is_status);
    }

    /// Real-time bytes answered by nothing: sent to both, not recorded.
    fn send(&mut self, bytes: &[u8]) {
        self.f.send(bytes);
        self.e.send(bytes);
    }

    /// Real-time override bytes, each followed by an empty line whose `ok` shows it
    /// was acted on (GRBL acts on real-time flags before it executes a line; flags that
    /// arrive together coalesce, so one at a time); not recorded.
    fn overrides(&mut self, bytes: &[u8]) {
        for &b in bytes {
            for c in [&mut self.f, &mut self.e] {
                c.send(&[b, b'\n']);
                c.read_through_line(LIMIT, ends_answer).unwrap();
            }
        }
    }

    /// Poll both with `?` until `state(report)` holds (bounded); not recorded. The
    /// one-time fields are not comparable afterwards (until a reset).
    fn settle(&mut self, state: impl Fn(&str) -> bool + Copy) {
        for c in [&mut self.f, &mut self.e] {
            let mut last = String::new();
            let ok = (0..5000).any(|_| {
                c.send(b"?");
                last = c.read_through_line(LIMIT, is_status).unwrap();
                let l = last.lines().last().unwrap_or("").to_string();
                if state(&l) {
                    return true;
                }
                std::thread::sleep(Duration::from_millis(10)); // pacing only
                false
            });
            assert!(ok, "never settled: {last}");
        }
        self.counters_known = false;
    }

    /// Soft reset both and read through the banner (recorded).
    fn reset(&mut self, name: &str) {
        self.case(name, &[0x18], |l| l.starts_with("Grbl 1.1h"));
        // The `[MSG:'$H'|'$X' to unlock]` after an alarm reset comes after the banner.
        self.counters_known = true;
    }

    /// Soft reset during motion: `ALARM:3`, the banner, the unlock message. grbl-sim
    /// sometimes prints the banner only once another byte arrives, so both get a `~`
    /// after the alarm (a cycle start does nothing in Alarm, on both).
    fn reset_in_motion(&mut self, name: &str) {
        self.case(name, &[0x18], |l| l.starts_with("ALARM:"));
        self.case(&format!("{name}: banner"), b"~", |l| {
            l.starts_with("[MSG:'$H'|'$X' to unlock]")
        });
    }

    /// A status report compared by its state and field names only (where the axes
    /// stopped depends on when a real-time byte arrived).
    fn status_shape(&mut self, name: &str) {
        self.f.send(b"?");
        self.e.send(b"?");
        let keep = self.counters_known;
        let shape = |r: String| {
            let l = r.lines().last().unwrap_or("").to_string();
            l.split('|')
                .map(|f| f.split(':').next().unwrap_or("").to_string())
                .filter(|f| keep || !(f == "WCO" || f == "Ov"))
                .collect::<Vec<_>>()
                .join("|")
        };
        let fa = shape(self.f.read_through_line(LIMIT, is_status).unwrap());
        let ea = shape(self.e.read_through_line(LIMIT, is_status).unwrap());
        self.cases.push(Case {
            name: name.into(),
            firmware: fa,
            emulator: ea,
            known: None,
        });
    }

    /// Start a motion with `line`, stop it with real-time `bytes` once X passed 2 mm,
    /// one side after the other, and return how far X went from the report taken with
    /// the stop to where the axes came to rest (a report `stopped` accepts).
    fn stop_distance(
        &mut self,
        line: &str,
        bytes: &[u8],
        stopped: impl Fn(&str) -> bool,
    ) -> [f64; 2] {
        let mut out = [0.0; 2];
        for (i, c) in [&mut self.f, &mut self.e].into_iter().enumerate() {
            c.send(format!("{line}\n").as_bytes());
            let ok = c.read_through_line(LIMIT, ends_answer).unwrap();
            assert_eq!(ok, "ok\r\n", "{line}");
            for polls in 0.. {
                assert!(polls < 5000, "never reached X 2");
                c.send(b"?");
                let r = c.read_through_line(LIMIT, is_status).unwrap();
                if mpos(&r)[0] > 2.0 {
                    break;
                }
                std::thread::sleep(Duration::from_millis(10)); // pacing only
            }
            let mut with_stop = vec![b'?'];
            with_stop.extend_from_slice(bytes);
            c.send(&with_stop);
            let first = c.read_through_line(LIMIT, is_status).unwrap();
            let mut last = String::new();
            for polls in 0.. {
                assert!(polls < 5000, "never stopped: {last}");
                c.send(b"?");
                last = c.read_through_line(LIMIT, is_status).unwrap();
                if stopped(last.lines().last().unwrap_or("")) {
                    break;
                }
                std::thread::sleep(Duration::from_millis(10)); // pacing only
            }
            out[i] = mpos(&last)[0] - mpos(&first)[0];
        }
        self.counters_known = false;
        out
    }

    /// Record a stop distance as a case: "decelerates" when it is v^2 / 2a (up to
    /// what the firmware's step segment buffer, a few 10 ms, and the report adds).
    fn decel_case(&mut self, name: &str, d: [f64; 2], feed: f64, accel: f64) {
        let v = feed / 60.0;
        let expected = v * v / (2.0 * accel);
        eprintln!(
            "{name}: firmware {:.3} mm, emulator {:.3} mm, v^2/2a {expected:.3} mm",
            d[0], d[1]
        );
        let class = |x: f64| {
            if x > expected - 0.2 && x < expected + 1.5 {
                format!("decelerates over v^2/2a = {expected:.2} mm")
            } else {
                format!("stops after {x:.3} mm")
            }
        };
        self.cases.push(Case {
            name: name.into(),
            firmware: class(d[0]),
            emulator: class(d[1]),
            known: None,
        });
    }

    /// The last case differs for a reason written down in docs/grbl-firmware.md (the
    /// test fails if it no longer differs, so the page stays true).
    fn known(&mut self, reason: &'static str) {
        self.cases.last_mut().expect("a case").known = Some(reason);
    }

    /// Assert every case identical but the known differences; print the table.
    fn finish(self, test: &str) {
        let same = self
            .cases
            .iter()
            .filter(|c| c.firmware == c.emulator)
            .count();
        let mut report = format!(
            "{test}: {} cases, {same} identical, {:.1} s\n",
            self.cases.len(),
            self.started.elapsed().as_secs_f64()
        );
        let mut unexpected = 0;
        for c in &self.cases {
            let differs = c.firmware != c.emulator;
            let tag = match (differs, c.known) {
                (false, None) => continue,
                (true, Some(_)) => "KNOWN",
                _ => {
                    unexpected += 1;
                    if differs {
                        "DIFF"
                    } else {
                        "NO LONGER DIFFERS"
                    }
                }
            };
            report.push_str(&format!(
                "{tag} {}\n  firmware: {:?}\n  emulator: {:?}\n",
                c.name, c.firmware, c.emulator
            ));
            if let Some(why) = c.known {
                report.push_str(&format!("  reason: {why}\n"));
            }
        }
        eprintln!("{report}");
        assert_eq!(unexpected, 0, "{report}");
    }
}

fn e_line(e: &mut TtyClient, l: &str) {
    e.send(format!("{l}\n").as_bytes());
    let a = e.read_through_line(LIMIT, ends_answer).unwrap();
    assert!(a.ends_with("ok\r\n"), "emulator refused {l}: {a}");
}

/// The comparable form of an answer: status reports without the `Pn:` field, with
/// positions and rates blanked while something moves, and without `WCO:`/`Ov:` when
/// their counters are not comparable.
fn normalise(answer: &str, counters_known: bool) -> String {
    answer
        .split_inclusive('\n')
        .filter(|l| !sim_percent_debug(l.trim_end()))
        .map(|l| {
            let t = l.trim_end();
            if !is_status(t) {
                return l.to_string();
            }
            let inner = &t[1..t.len() - 1];
            let mut parts = inner.split('|');
            let state = parts.next().unwrap_or("");
            let moving = matches!(state, "Run" | "Jog" | "Home" | "Hold:1" | "Door:1");
            let fields: Vec<String> = parts
                .filter(|f| !f.starts_with("Pn:"))
                .filter(|f| counters_known || !(f.starts_with("WCO:") || f.starts_with("Ov:")))
                .map(|f| {
                    let blank = moving
                        && ["MPos:", "WPos:", "FS:", "F:"]
                            .iter()
                            .any(|p| f.starts_with(p));
                    match (blank, f.split_once(':')) {
                        (true, Some((k, _))) => format!("{k}:*"),
                        _ => f.to_string(),
                    }
                })
                .collect();
            let mut s = format!("<{state}");
            for f in fields {
                s.push('|');
                s.push_str(&f);
            }
            s.push_str(">\r\n");
            s
        })
        .collect()
}

/// grbl-sim prints its clock (`masterclock sim_time`, serial.c: "debugging") on the
/// serial line for every `%` byte it receives; GRBL itself never sends such a line.
fn sim_percent_debug(l: &str) -> bool {
    l.split_once(' ').is_some_and(|(ticks, time)| {
        ticks.parse::<u64>().is_ok() && time.parse::<f64>().is_ok() && time.contains('.')
    })
}

/// The machine position in a status report.
fn mpos(report: &str) -> [f64; 3] {
    let l = report
        .lines()
        .rev()
        .find(|l| is_status(l))
        .unwrap_or_else(|| panic!("no status in {report:?}"));
    let p = l
        .split('|')
        .find_map(|f| f.strip_prefix("MPos:"))
        .unwrap_or_else(|| panic!("no MPos in {l}"));
    let v: Vec<f64> = p.split(',').map(|x| x.parse().unwrap()).collect();
    [v[0], v[1], v[2]]
}

fn idle(l: &str) -> bool {
    l.starts_with("<Idle")
}

#[test]
fn connect_info_settings_parameters_and_parser_state() {
    let mut p = Pair::start();
    p.line("$I");
    p.line("$$");
    p.line("$#");
    p.line("$G");
    p.line("$N");
    p.line("$");
    p.status("status at rest");
    p.status("status again");
    p.line("$I=my machine");
    p.line("$I");
    p.reset("soft reset at rest");
    p.status("status after reset");
    p.finish("connect");
}

#[test]
fn first_power_up_and_second_power_up() {
    let mut fw = Firmware::Grbl11h
        .start()
        .unwrap_or_else(|e| panic!("real GRBL 1.1h: {e}"));
    let mut c = fw.open().unwrap_or_else(|e| panic!("{e}"));
    let boot = c
        .read_through_line(LIMIT, |l| l.starts_with("Grbl 1.1h"))
        .unwrap();
    assert!(boot.starts_with("error:7\r\n$0=10\r\n"), "{boot}");
    assert!(boot.ends_with("\r\nGrbl 1.1h ['$' for help]\r\n"), "{boot}");
    c.send(b"$I\n");
    let i = c.read_through_line(LIMIT, |l| l == "ok").unwrap();
    assert_eq!(i, "[VER:1.1h.20190830:]\r\n[OPT:V,15,128]\r\nok\r\n");
    drop(c);
    let dir = fw.keep_workdir();
    drop(fw);
    // Second power-up: the EEPROM is valid, only the banner; the emulator's power-up.
    let fw = Firmware::Grbl11h
        .start_in(&dir)
        .unwrap_or_else(|e| panic!("{e}"));
    let mut c = fw.open().unwrap();
    let boot = c
        .read_through_line(LIMIT, |l| l.starts_with("Grbl 1.1h"))
        .unwrap();
    let emu = Emulator::start();
    let mut e = TtyClient::open(std::path::Path::new(&emu.path())).unwrap();
    let eboot = e
        .read_through_line(LIMIT, |l| l.starts_with("Grbl 1.1h"))
        .unwrap();
    assert_eq!(boot, eboot);
    drop(c);
    drop(fw);
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn errors_bad_words_unsupported_commands_and_codes() {
    let mut p = Pair::start();
    for l in [
        "G1 X1",         // no feed: error:22
        "X1 X2",         // repeated word: error:25
        "G1 G0 X1",      // modal group violation: error:21
        "G0 X",          // bad number: error:2
        "Q1",            // unsupported word: error:20
        "G5 X1",         // unsupported command: error:20
        "G10 X1",        // no L, no P: error:28
        "G10 P1 X1",     // no L: error:3
        "G10 L3 P1 X1",  // unsupported L: error:3
        "G10 L2 P10 X1", // P out of range: error:29
        "G10 L2 X1",     // no P: the active system
        "G10 L20 Y2",    // no P: the active system
        "G10 L2 P2 Z3",
        "$#",
        "G55",
        "G10 L20 X5",
        "$#",
        "G54",
        "$G",
        "G2 X1 F100",                   // no offsets: error:26
        "G91 G2 X0.2 I0.1 R1 F100",     // R with I: error:36 (issue 38)
        "G91 G17 G2 X0.2 I0.1 K1 F100", // offsets take K too in G17: ok
        "G4 P0",                        // the arc ends before the `$` lines (error:8 while it runs)
        "G90",
        "G4", // no P: error:28
        "M7", // mist not built: error:20
        "M100",
        "T1",
        "G0 X1.2.3",
        "$99=1",   // no such setting: error:3
        "$100=-1", // negative: error:4
        "$10",     // error:3
        "$ABC",    // error:3
        "$x=1",
        "$N2=G0",
        "$J=X1",         // no feed: error:22? (jog without F)
        "$J=G1 X1 F100", // G1 in a jog: error:16? / jog motion of G1
        "$J=X1 F100 M3", // a non-jog word: error:16
        "G53 G1 X1 F100",
        "G28.1",
        "G30.1",
        "$#",
        "N1 G0 X0",
        "N99999999 G0 X0",
        "G0 X0 ; comment",
        "G0 (comment) X0",
        "g0x0",
        "",
        "G21G90G17G94G54M5M9",
        "$G",
    ] {
        p.line(l);
    }
    p.finish("errors");
}

#[test]
fn g92_offsets_and_inches() {
    let mut p = Pair::start();
    for l in [
        "G92 X10 Y-5",
        "$#",
        "G92.1",
        "$#",
        "G92 Z2",
        "G92.2",
        "$#",
        "G92.3",
        "$#",
        "G20",
        "G92 X1",
        "$#",
        "$G",
        "G21",
        "$13=1",
        "$#",
        "$G",
        "G10 L2 P1 X25.4 Y-12.7",
    ] {
        p.line(l);
    }
    p.status("status in inches");
    p.line("$13=0");
    p.status("status in mm");
    p.reset("reset");
    p.line("$13=1");
    p.status("status in inches after reset (WCO:)");
    p.line("G1 X0.1 F500");
    // GRBL answers a motion line before its planner starts it (a poll at that moment
    // reads Idle); a dwell is answered once the planner is empty, on both.
    p.line("G4 P0");
    p.status("in inches at rest");
    p.line("$13=0");
    p.finish("offsets");
}

#[test]
fn check_mode_sleep_alarms_and_unlock() {
    let mut p = Pair::start();
    p.line("$C");
    p.line("G0 X5");
    p.line("G1 X1");
    p.line("$#");
    p.status("status in check mode");
    p.case("$C off", b"$C\n", |l| l.starts_with("Grbl 1.1h"));
    p.status("status after check mode");
    p.line("$G");
    // An alarm from a soft reset during motion.
    p.line("G1 X5 F200");
    p.firmware_until("<Run");
    p.status("moving");
    p.reset_in_motion("reset in motion");
    // Where the reset stopped the axes depends on when it came.
    p.status_shape("alarm");
    p.line("G0 X0");
    p.line("$G");
    p.line("$$");
    p.line("$#");
    p.line("$J=X1 F100");
    p.case("reset in alarm", &[0x18], |l| {
        l.starts_with("[MSG:'$H'|'$X' to unlock]")
    });
    p.line("$X");
    p.line("G0 X0");
    p.line("G4 P0");
    p.status("unlocked");
    p.line("$X");
    // `ok` first, then `[MSG:Sleeping]` once the firmware has stopped everything (it may
    // come after a status poll): read through the message before polling.
    p.case("$SLP", b"$SLP\n", |l| l.starts_with("[MSG:Sleeping]"));
    p.status("sleep");
    p.case("reset from sleep", &[0x18], |l| {
        l.starts_with("[MSG:'$H'|'$X' to unlock]")
    });
    p.line("$X");
    p.line("$H");
    p.line("$22=1");
    // Homing locks at power-up only: a soft reset from Idle stays Idle.
    p.reset("reset with homing on");
    p.status("idle with homing on");
    p.line("$22=0");
    p.line("$X");
    // `$RST=` resets the controller after its `ok`; what arrives before the banner is
    // flushed, so the next byte waits for it.
    p.case("$RST=#", b"$RST=#\n", banner);
    p.case("after $RST=#", b"?", is_status);
    p.line("$N0=G21 G90");
    p.line("$N");
    p.case("reset runs the startup line", &[0x18], |l| {
        l.starts_with(">G21")
    });
    p.line("$N0=");
    p.case("$RST=$", b"$RST=$\n", banner);
    p.case("after $RST=$", b"$$\n", ends_answer);
    p.known(
        "`$RST=$` restores the build's defaults: GRBL's defaults.h, the emulator's the \
         simulated machine's (steps, travel)",
    );
    p.finish("alarms");
}

#[test]
fn probing_messages() {
    let mut p = Pair::start();
    // The simulator's probe pin reads "triggered" ($6=0): a move toward the work fails
    // at once.
    p.case("G38.2 already triggered", b"G38.2 Z-1 F100\n", |l| {
        l.starts_with("ALARM:") || ends_answer(l)
    });
    p.reset("reset");
    p.line("$X");
    p.line("$6=1");
    p.case("G38.3 miss", b"G38.3 Z-0.5 F300\n", ends_answer);
    p.line("$#");
    p.case("G38.2 miss", b"G38.2 Z-1 F300\n", |l| {
        l.starts_with("ALARM:") || ends_answer(l)
    });
    p.reset("reset after probe alarm");
    p.line("$X");
    p.line("$#");
    p.line("$6=0");
    p.case("G38.4 never loses contact", b"G38.4 X0.5 F300\n", |l| {
        l.starts_with("ALARM:") || ends_answer(l)
    });
    p.reset("reset 2");
    p.line("$X");
    p.case("G38.5 miss", b"G38.5 X1 F300\n", ends_answer);
    p.line("$#");
    p.finish("probing");
}

/// Feed hold `!` and resume `~`: GRBL decelerates with `$120`; the hold distance
/// (from the report taken with the hold to the `Hold:0` position) is v^2 / 2a.
#[test]
fn feed_hold_decelerates_and_resume_completes() {
    let mut p = Pair::start();
    for l in ["$110=1000", "$111=1000", "$120=100", "$121=100"] {
        p.line(l);
    }
    let d = p.stop_distance("G1 X10 F1000", b"!", |l| l.starts_with("<Hold:0"));
    p.decel_case("feed hold at F1000, $120=100", d, 1000.0, 100.0);
    p.status_shape("held");
    p.send(b"~");
    p.line("G4 P0");
    p.status("resumed to the end");
    // A hold at rest, and a resume.
    p.send(b"!");
    p.settle(|l| l.starts_with("<Hold:0"));
    p.status("hold at rest");
    p.send(b"~");
    p.settle(idle);
    p.status("resume at rest");
    // A reset during a complete hold: no alarm.
    p.line("G1 X0 F1000");
    p.send(b"!");
    p.settle(|l| l.starts_with("<Hold:0"));
    p.reset("reset in Hold:0");
    p.status_shape("after a reset in Hold:0");
    p.finish("feed hold");
}

/// Jog, jog cancel 0x85 (decelerates too), and a jog's errors.
#[test]
fn jogs_and_jog_cancel() {
    let mut p = Pair::start();
    for l in ["$110=1000", "$111=1000", "$120=100", "$121=100"] {
        p.line(l);
    }
    p.line("$J=G91 X2 F600");
    p.settle(idle);
    p.status("after a jog");
    p.line("$J=G90 G20 X0.1 F20");
    p.settle(idle);
    p.status("after an inch jog");
    p.line("$G");
    p.line("$J=G53 X0 F1000");
    p.settle(idle);
    let d = p.stop_distance("$J=X20 F1000", &[0x85], idle);
    p.decel_case("jog cancel at F1000, $120=100", d, 1000.0, 100.0);
    p.status_shape("after the jog cancel");
    p.line("$J=G90 X3 F1000");
    p.settle(idle);
    p.status("an absolute jog after the cancel");
    p.line("$J=G91 X-1 F1000");
    p.settle(idle);
    p.line("$J=G91 X1 F1000");
    p.settle(idle);
    p.send(&[0x85]);
    p.status("jog cancel at rest");
    p.line("$J=X1");
    p.line("$J=X1 F100 S10");
    p.line("$J=G0 X1 F100");
    p.line("$J=G4 P1");
    p.line("$J=G91 F100");
    p.finish("jogs");
}

/// Overrides: the `Ov:` field and limits.
#[test]
fn overrides() {
    let mut p = Pair::start();
    p.status("first");
    p.status("second (Ov: follows WCO:)");
    p.overrides(&[0x91, 0x91, 0x93]);
    p.status("feed +21");
    p.overrides(&[0x95, 0x96]);
    p.status("rapid 50 then 25");
    p.overrides(&[0x9A, 0x9C, 0x9C]);
    p.status("spindle +8");
    p.overrides(&[0x91; 15]);
    p.status("feed at most 200");
    p.overrides(&[0x92; 25]);
    p.status("feed at least 10");
    p.overrides(&[0x90, 0x94, 0x99]);
    p.status("all reset");
    p.line("M3 S1000");
    p.status("spindle on (A:S)");
    p.line("M8");
    p.status("flood (A:SF)");
    p.overrides(&[0xA0]);
    p.status("flood toggled off");
    p.line("M5 M9");
    p.status("off");
    p.finish("overrides");
}

/// `$100` changed after a move: GRBL keeps the step count, so the position in mm
/// changes; the next move goes to its target in the new steps.
#[test]
fn changing_steps_per_mm_keeps_the_step_count() {
    let mut p = Pair::start();
    p.line("G1 X2 F500");
    p.line("G4 P0");
    p.status("at X2");
    p.line("$100=500");
    p.status("after $100=500");
    p.line("$#");
    p.line("G1 X3 F500");
    p.line("G4 P0");
    p.status("at X3 in new steps");
    p.line("$100=250");
    p.status("back to 250");
    p.finish("steps per mm");
}

/// G-code constructs GRBL's line filter decides (issue 38: `%`, spaces inside a number,
/// an unclosed `(`, `/` mid-line): the firmware's answer and where it went, the
/// emulator's (compared as every case), and what the rewriters make of the same line
/// (`rewrite::dialect::read_line`, which the program rewrite and the pass-through both
/// use; the code the pass-through answers is `proxy::refusal_code`): refused with the
/// firmware's code, or accepted with the firmware's target.
#[test]
fn gcode_constructs_are_read_by_rewrite_and_proxy_as_the_firmware_reads_them() {
    let mut p = Pair::start();
    let mut gateway = protocol::grbl::gcode::Interpreter::new();
    for l in [
        "%",
        "%G0 X1",
        "  % end",
        "G0 X1 0",
        "G0 X2 (an unclosed comment",
        "(only an unclosed comment",
        "G0 X3 / Y1",
        "/G0 Y2",
        "G0 X0 (a;b) Y0",
        "G0 X1 ( Y5",
        "G0 X 4",
        "G0 X- 0 . 5",
        "G0 X0 Y0",
    ] {
        p.line(l);
        let firmware = p.cases.last().expect("a case").firmware.clone();
        let gateway_answer = match rewrite::dialect::read_line(&mut gateway, l, 1) {
            Ok(_) => "ok".to_string(),
            Err(e) => format!("error:{}", proxy::refusal_code(&e)),
        };
        assert_eq!(firmware.trim_end(), gateway_answer, "`{l}`");
        p.line("G4 P0");
        p.status(&format!("after `{l}`"));
        let at = mpos(&p.cases.last().expect("a case").firmware);
        for k in 0..3 {
            assert!(
                (at[k] - gateway.position[k]).abs() < 1e-3,
                "`{l}`: the firmware is at {at:?}, the rewriters' interpreter at {:?}",
                &gateway.position[..3]
            );
        }
    }
    p.finish("constructs");
}

/// A soft-limit alarm (`$20=1`, which needs `$22=1`): a move past the travel is
/// `ALARM:2` and `[MSG:Reset to continue]`; the firmware then blocks everything but
/// a reset (even status reports: its loop does not report); after the reset it finishes the offending line.
#[test]
fn soft_limit_alarm_and_the_reset_that_follows() {
    let mut p = Pair::start();
    p.line("$22=1");
    p.line("$20=1");
    // GRBL's machine space is negative from home ($23=0): X1 is past the travel.
    p.case("G0 X1 past the travel", b"G0 X1\n", |l| {
        l.starts_with("[MSG:Reset to continue]")
    });
    p.case("reset after the soft limit", &[0x18], |l| {
        l.starts_with("[MSG:'$H'|'$X' to unlock]")
    });
    p.line("G0 X0");
    p.line("$X");
    p.line("$20=0");
    p.line("$22=0");
    p.line("G0 X-1");
    p.line("G4 P0");
    p.status("after unlocking");
    p.finish("soft limit");
}

/// grblHAL starts on its pty in both builds (the harness other tests use).
#[test]
fn grblhal_three_and_six_axes_start_and_answer() {
    for (fw, axes) in [(Firmware::GrblHal3, "XYZ"), (Firmware::GrblHal6, "XYZABC")] {
        let run = fw.start().unwrap_or_else(|e| panic!("{e}"));
        let mut c = run.open().unwrap_or_else(|e| panic!("{e}"));
        c.read_through_line(LIMIT, |l| l.starts_with("GrblHAL"))
            .unwrap_or_else(|e| panic!("{fw:?}: {e}"));
        c.send(b"?");
        let s = c.read_through_line(LIMIT, is_status).unwrap();
        let n = s
            .split('|')
            .find_map(|f| f.strip_prefix("MPos:"))
            .map(|p| p.split(',').count())
            .unwrap_or(0);
        assert_eq!(n, axes.len(), "{fw:?}: {s}");
    }
}
