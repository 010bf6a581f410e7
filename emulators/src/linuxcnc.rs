//! The rig follows a real LinuxCNC: the simulated stage is put where LinuxCNC's joints
//! are commanded, `joint.N.motor-pos-cmd` (the position after LinuxCNC's own
//! compensation and backlash correction), read at full precision from HAL through
//! Debian's python3 `hal` module (`halcmd` prints 7 significant digits only).
//!
//! Homing: a LinuxCNC without home switches (the test peer's `HOME_SEARCH_VEL = 0`)
//! declares the current position home and keeps the motor where it is by setting
//! `joint.N.motor-offset`; the simulated machine homes to its own switch at the same
//! moment. So the simulated machine's command is `motor-pos-cmd - motor-offset`: the
//! motor command measured from where LinuxCNC last homed, which is the simulated
//! home. Worked example: homed again at X 50, LinuxCNC says X 0, `motor-offset` 50,
//! `motor-pos-cmd` 50.000012 (a 12 nm trim): the simulated X is commanded to 0.000012.
//!
//! Following: while LinuxCNC moves (an MDI move, a program in auto mode), the reader
//! samples the joints' motor commands at a steady rate ([`LinuxcncFollower::start`],
//! every `period_ms` of wall time, a sample only when the command changed; between
//! samples it polls every 0.5 ms, and where a joint's command turns back it sends the
//! turning point as a sample at once: a backlash take-up of a few um lasts a few ms,
//! and a stage that never saw the turn would stay in its backlash) and the
//! simulated machine moves straight from each sample to the next, so its trace is the
//! path LinuxCNC really commands (arcs, blends, its compensation as it ramps), within
//! the chord of one period (at 3000 mm/min and 4 ms: 0.2 mm of path, 0.17 um of chord
//! error on a 30 mm radius; a period stretched by a loaded computer makes it longer). When the move has ended ([`LinuxcncFollower::settle`]) the
//! reader stops sampling, waits until each joint's backlash filter has reached its
//! correction (the motor command has settled) and the machine goes to that last
//! command: the end point does not depend on when the samples fell. The two joints of
//! a sample are read within one servo period (read X, Y, X again until X has not
//! changed), so a sample is one point of LinuxCNC's path, not two halves of two.
//!
//! Simulated time: each sample is a straight move at the follower's feed, from rest at
//! the stage's own acceleration; the simulated clock runs on by those moves, not by
//! LinuxCNC's wall clock. LinuxCNC must run on this computer (HAL is shared memory).

use std::io::{BufRead, BufReader, Write};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::mpsc::{channel, Receiver};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use world::{lock, SharedRig};

/// Debian's python3 with LinuxCNC's `hal` module (package `python3-linuxcnc`, which
/// `linuxcnc-uspace` depends on).
pub const HAL_PYTHON: &str = "/usr/bin/python3";

/// A command this far beyond an end of the simulated travel (0..T) is held at the end:
/// LinuxCNC's own table trims a joint by a fraction of a micrometre at its home
/// position, where the simulated stage's travel begins (worked example: homed at 0, the
/// forward trim of an exported table at 0 is -0.17 um; the first samples of a move
/// from there command -0.00017 mm, the simulated X stays at 0 until the command
/// turns positive).
pub const TRAVEL_SLACK_MM: f64 = 0.001;

/// The sampling period while LinuxCNC moves, ms of wall time.
pub const SAMPLE_PERIOD_MS: f64 = 4.0;

/// The reader. Requests, one per line on stdin:
/// * `S j0 j1 PERIOD_MS`: sample those joints every period from now on; each sample
///   whose values changed is printed `P v0 v1`;
/// * `E j0 j1`: stop sampling; once each joint's backlash filter has reached its
///   correction, print `R v0 v1`.
///
/// Values are `motor-pos-cmd - motor-offset`, repr (full precision).
const READER: &str = r#"
import hal, os, select, sys, time
c = hal.component("xygw_rig_follower_%d" % os.getpid())
g = hal.get_value
def values(js):
    # one servo period: the first joint read again unchanged after the others
    for _ in range(50):
        a = g("joint.%d.motor-pos-cmd" % js[0])
        v = [a] + [g("joint.%d.motor-pos-cmd" % j) for j in js[1:]]
        if g("joint.%d.motor-pos-cmd" % js[0]) == a:
            break
    return [x - g("joint.%d.motor-offset" % j) for x, j in zip(v, js)]
def text(v):
    return " ".join(repr(x) for x in v)
def cmd(js):
    return text(values(js))
def settled(js):
    for _ in range(5000):
        if all(g("joint.%d.backlash-filt" % j) == g("joint.%d.backlash-corr" % j) for j in js):
            break
        time.sleep(0.001)
    return cmd(js)
buf = b""
stream = None
last = None
# Between two samples the joints are polled every TURN_POLL s: where a joint turns
# back (a backlash take-up of a few um lasts a few ms), the turning point is sent at
# once as a sample, so the simulated stage reverses where LinuxCNC did.
TURN_POLL = 0.0005
def send(s):
    global last
    if s != last:
        sys.stdout.write("P " + s + "\n")
        sys.stdout.flush()
        last = s
while True:
    wait = None if stream is None else max(0.0, min(due, poll_due) - time.monotonic())
    ready, _, _ = select.select([0], [], [], wait)
    if not ready:
        now = time.monotonic()
        v = values(stream)
        if prev is not None:
            for k in range(len(v)):
                d = v[k] - prev[k]
                if d != 0.0:
                    if heading[k] != 0.0 and (d > 0.0) != (heading[k] > 0.0):
                        send(text(prev))
                    heading[k] = d
        prev = v
        poll_due = now + TURN_POLL
        if now >= due:
            send(text(v))
            due += period
            if due < now:
                due = now
        continue
    data = os.read(0, 4096)
    if not data:
        break
    buf += data
    while b"\n" in buf:
        line, buf = buf.split(b"\n", 1)
        w = line.decode().split()
        if w and w[0] == "S":
            stream = [int(j) for j in w[1:-1]]
            period = float(w[-1]) / 1000.0
            due = time.monotonic()
            poll_due = due
            last = None
            prev = None
            heading = [0.0] * len(stream)
        elif w and w[0] == "E":
            stream = None
            sys.stdout.write("R " + settled([int(j) for j in w[1:]]) + "\n")
            sys.stdout.flush()
c.exit()
"#;

fn io_error(message: String) -> std::io::Error {
    std::io::Error::other(message)
}

/// What the reader thread hands back for a settle request: the settled command, or
/// the first thing that went wrong since the last settle.
type Settled = Result<[f64; 2], String>;

/// The simulated stage (X and Y of the rig's machine) slaved to two LinuxCNC joints.
pub struct LinuxcncFollower {
    rig: SharedRig,
    /// The joints of X and Y.
    joints: [u8; 2],
    child: Child,
    /// Closed on drop: the reader then removes its HAL component and ends.
    stdin: Option<ChildStdin>,
    settled: Receiver<Settled>,
    thread: Option<JoinHandle<()>>,
    samples: SampleLog,
}

/// The simulated machine's position after each sample and settle, while recording.
type SampleLog = Arc<Mutex<Option<Vec<[f64; 2]>>>>;

/// Parse `TAG v0 v1`.
fn values(line: &str) -> Option<[f64; 2]> {
    let mut w = line.split_whitespace().skip(1);
    let mut v = [0.0; 2];
    for x in &mut v {
        *x = w.next()?.parse::<f64>().ok().filter(|v| v.is_finite())?;
    }
    w.next().is_none().then_some(v)
}

/// Move the simulated machine to `target` (a move from rest at `feed_mm_min`, run to
/// its end). Nothing moves while it is not homed.
fn move_rig(rig: &SharedRig, target: [f64; 2], feed_mm_min: f64) -> Result<[f64; 2], String> {
    let mut rig = lock(rig);
    let m = rig.machine_mut();
    let mut target = target;
    for (k, t) in target.iter_mut().enumerate() {
        let travel = m.axis_config(k).travel_mm;
        if (-TRAVEL_SLACK_MM..0.0).contains(t) {
            *t = 0.0;
        } else if *t > travel && *t <= travel + TRAVEL_SLACK_MM {
            *t = travel;
        }
    }
    if m.is_homed() && m.position_mm() != target {
        m.start_move(target, feed_mm_min).map_err(|e| {
            format!("the simulated stage cannot follow LinuxCNC to {target:?}: {e}")
        })?;
        m.finish_motion();
    }
    Ok(m.position_mm())
}

impl LinuxcncFollower {
    /// Start the HAL reader for joints `joints` (X, Y); the simulated machine follows
    /// at `feed_mm_min` (its own clock's figure).
    pub fn new(rig: SharedRig, joints: [u8; 2], feed_mm_min: f64) -> std::io::Result<Self> {
        let mut child = Command::new(HAL_PYTHON)
            .args(["-c", READER])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .map_err(|e| {
                io_error(format!(
                    "{HAL_PYTHON} (LinuxCNC's python3 `hal` module): {e}"
                ))
            })?;
        let stdin = child
            .stdin
            .take()
            .ok_or_else(|| io_error("no stdin".into()))?;
        let stdout = BufReader::new(
            child
                .stdout
                .take()
                .ok_or_else(|| io_error("no stdout".into()))?,
        );
        let (tx, settled) = channel();
        let follow = rig.clone();
        let samples: SampleLog = Default::default();
        let log = samples.clone();
        // Two threads: one only reads the pipe into a queue, so the reader never
        // waits on a full pipe (a late sample would be a gap in the path) however long
        // the simulated moves take; the other applies the samples in order and hands
        // back each settled command once every sample before it is applied.
        let (lines_tx, lines) = channel::<String>();
        let pipe = std::thread::spawn(move || {
            for line in stdout.lines() {
                let Ok(line) = line else { break };
                if lines_tx.send(line).is_err() {
                    break;
                }
            }
        });
        let thread = std::thread::spawn(move || {
            let mut failed: Option<String> = None;
            for line in lines {
                let parsed = values(&line).ok_or_else(|| {
                    format!(
                        "the HAL reader said {}",
                        protocol::text::escape_bytes(line.as_bytes())
                    )
                });
                let applied = parsed.and_then(|v| {
                    let at = move_rig(&follow, v, feed_mm_min)?;
                    if let Some(log) = lock(&log).as_mut() {
                        log.push(at);
                    }
                    Ok(v)
                });
                if line.starts_with("R ") {
                    let reply = match failed.take() {
                        Some(e) => Err(e),
                        None => applied,
                    };
                    if tx.send(reply).is_err() {
                        break;
                    }
                } else if let Err(e) = applied {
                    failed.get_or_insert(e);
                }
            }
            let _ = pipe.join();
        });
        Ok(Self {
            rig,
            joints,
            child,
            stdin: Some(stdin),
            settled,
            thread: Some(thread),
            samples,
        })
    }

    fn request(&mut self, line: String) -> std::io::Result<()> {
        let stdin = self
            .stdin
            .as_mut()
            .ok_or_else(|| io_error("the HAL reader is closed".into()))?;
        writeln!(stdin, "{line}")?;
        stdin.flush()
    }

    /// LinuxCNC is about to move: from now on the simulated machine follows its joints'
    /// motor commands, sampled every `period_ms`.
    pub fn start(&mut self, period_ms: f64) -> std::io::Result<()> {
        let [x, y] = self.joints;
        self.request(format!("S {x} {y} {period_ms}"))
    }

    /// LinuxCNC's move has ended: sampling stops, and the simulated machine goes to the
    /// settled motor commands, which are returned. An error names what went wrong while
    /// following (a sample the simulated stage could not reach).
    pub fn settle(&mut self) -> std::io::Result<[f64; 2]> {
        let [x, y] = self.joints;
        self.request(format!("E {x} {y}"))?;
        match self.settled.recv() {
            Ok(Ok(v)) => Ok(v),
            Ok(Err(e)) => Err(io_error(e)),
            Err(_) => Err(io_error(
                "the HAL reader ended (is LinuxCNC running on this computer?)".into(),
            )),
        }
    }

    /// Record from now on where the simulated machine was put by each sample and
    /// settle (controller positions, machine mm): each is a point of the path LinuxCNC
    /// commanded, whatever the wall time between them (what lies between two is the
    /// simulated stage's straight move, a chord).
    pub fn record_samples(&mut self) {
        *lock(&self.samples) = Some(Vec::new());
    }

    /// The positions recorded since [`LinuxcncFollower::record_samples`]; recording stops.
    pub fn take_samples(&mut self) -> Vec<[f64; 2]> {
        lock(&self.samples).take().unwrap_or_default()
    }

    /// LinuxCNC has homed: the simulated machine homes (a new homing error), then goes
    /// where the joints are commanded.
    pub fn homed(&mut self) -> std::io::Result<[f64; 2]> {
        lock(&self.rig).machine_mut().home();
        self.settle()
    }
}

impl Drop for LinuxcncFollower {
    fn drop(&mut self) {
        // End of input: the reader leaves HAL cleanly (`c.exit()`); a killed one would
        // leave its component behind. Killed only if it has not ended within 2 s.
        drop(self.stdin.take());
        let mut ended = false;
        for _ in 0..200 {
            if let Ok(Some(_)) = self.child.try_wait() {
                ended = true;
                break;
            }
            std::thread::sleep(std::time::Duration::from_millis(10));
        }
        if !ended {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::values;

    #[test]
    fn reader_lines() {
        assert_eq!(values("P 1.5 -2e-3"), Some([1.5, -0.002]));
        assert_eq!(values("R 0.0 0.0"), Some([0.0, 0.0]));
        assert_eq!(values("P 1.5"), None);
        assert_eq!(values("P 1 2 3"), None);
        assert_eq!(values("P nan 2"), None);
        assert_eq!(values("Traceback (most recent call last):"), None);
    }
}
