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
//! Following: LinuxCNC's realtime `sampler` component, in the servo thread after
//! `motion-controller` ([`SAMPLER_HAL`]), puts every servo period's motor commands and
//! motor offsets of X, Y and Z into a FIFO in shared memory; the reader (LinuxCNC's
//! python3 `hal.stream`, the FIFO `halsampler` reads) takes every sample, in order,
//! checks that none was lost (the sample numbers follow each other, the FIFO never
//! overran: otherwise the follow fails, naming the lost samples), and while LinuxCNC
//! moves (an MDI move, a program in auto mode: [`LinuxcncFollower::start`]) sends each
//! sample whose command changed. The simulated machine moves straight from each sample
//! to the next, so its trace is the path LinuxCNC really commands (arcs, blends, its
//! compensation and backlash take-ups as they ramp), servo period by servo period
//! (at 3000 mm/min and 1 ms: 0.05 mm of path, 0.01 um of chord error on a 30 mm
//! radius), however loaded the computer is: the FIFO holds 16 s. When the move has
//! ended ([`LinuxcncFollower::settle`]) the reader waits until motion is in position
//! (`motion.in-position`) and each joint's backlash filter has reached its correction,
//! takes the samples up to that settled command,
//! and the machine goes there: the end point is LinuxCNC's last command.
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

/// The sampler channel the follower reads (`sampler.0`, HAL stream key
/// `hal.sampler_base + 0`).
pub const SAMPLER_CHANNEL: u32 = 0;

/// The sampler's pins, in order: `motor-pos-cmd` and `motor-offset` of the joints of X,
/// Y and Z (`sampler.0.pin.0` .. `pin.5`; [`SAMPLER_HAL`] wires them).
pub const SAMPLER_CFG: &str = "ffffff";

/// The FIFO's depth, servo periods: 16 s at LinuxCNC's usual 1 ms, which the reader
/// (draining every 2 ms) never comes near; an overrun is an error all the same.
pub const SAMPLER_DEPTH: u32 = 16384;

/// What LinuxCNC's HAL needs for the follower (a `HALFILE` after the machine's own):
/// the realtime `sampler` in the servo thread after `motion-controller`, fed by the
/// joints' `motor-pos-cmd` (here the test peer's `x.hal` signals `jN-motor-pos`, which
/// carry them) and `motor-offset`.
pub const SAMPLER_HAL: &str = "\
# The rig's follower (emulators::linuxcnc): every servo period's motor commands.
loadrt sampler depth=16384 cfg=ffffff
addf sampler.0 servo-thread
net j0-motor-pos sampler.0.pin.0
net xygw-j0-motor-offset joint.0.motor-offset => sampler.0.pin.1
net j1-motor-pos sampler.0.pin.2
net xygw-j1-motor-offset joint.1.motor-offset => sampler.0.pin.3
net j2-motor-pos sampler.0.pin.4
net xygw-j2-motor-offset joint.2.motor-offset => sampler.0.pin.5
";

/// The reader: attaches to the sampler's FIFO (`hal.stream`, the FIFO `halsampler`
/// reads; `halsampler` itself prints floats `%f`, 6 decimals, 1 nm, not the full
/// double), says `OK DEPTH` or `X why`, and then takes requests, one per line on stdin:
/// * `S k..`: follow the sampler's slots k (0 X, 1 Y, 2 Z) from now on: every sample
///   whose command changed is printed `P v..`;
/// * `E j..`: stop following; once joints j's backlash filters have reached their
///   corrections, every sample up to the settled command is printed and then `R v..`.
///
/// Values are `motor-pos-cmd - motor-offset`, repr (full precision). A lost sample (a
/// gap in the sample numbers, an overrun of the FIFO) is said at once: `X why`.
const READER: &str = r#"
import hal, os, select, sys, time
c = hal.component("xygw_rig_follower_%d" % os.getpid())
g = hal.get_value
def out(s):
    sys.stdout.write(s + "\n")
    sys.stdout.flush()
try:
    stream = hal.stream(c, hal.sampler_base + CHANNEL)
except OSError as e:
    out("X LinuxCNC's HAL has no sampler channel %d (%s): load it in the servo thread as the follower's HAL file does (loadrt sampler depth=%d cfg=%s, addf sampler.%d servo-thread, each joint's motor-pos-cmd and motor-offset on its pins)" % (CHANNEL, e, DEPTH, CFG, CHANNEL))
    sys.exit(0)
types = stream.element_types
if isinstance(types, bytes):
    types = types.decode()
if types != CFG:
    out("X LinuxCNC's sampler channel %d samples %r, not %r (motor-pos-cmd and motor-offset of X, Y, Z)" % (CHANNEL, types, CFG))
    sys.exit(0)
# What the sampler wrote before the follower attached is not followed; the FIFO may
# have been full (and overrunning) since LinuxCNC started: empty it first, then count.
while stream.read() is not None:
    pass
overruns = stream.num_overruns
out("OK %d" % stream.maxdepth)
last_no = None
failed = False
def fail(message):
    global failed
    if not failed:
        out("X " + message)
    failed = True
def read():
    # One sample, or None when the FIFO is empty. Every servo period is one sample,
    # numbered: a gap or an overrun is a lost period, said at once.
    global last_no, overruns
    v = stream.read()
    if v is None:
        return None
    no = stream.sampleno
    if last_no is not None and no != (last_no + 1) & 0xffffffff:
        fail("samples %d..%d of LinuxCNC's servo thread were lost (the follower read too slowly)" % (last_no + 1, no - 1))
    last_no = no
    if stream.num_overruns != overruns:
        fail("LinuxCNC's sampler FIFO overran %d times (depth %d): servo periods were lost" % (stream.num_overruns - overruns, stream.maxdepth))
        overruns = stream.num_overruns
    return v
following = None
sent = None
def take(v):
    # The sample's command of the followed joints; sent when it changed.
    global sent
    if following is None:
        return None
    w = [v[2 * k] - v[2 * k + 1] for k in following]
    if w != sent:
        out("P " + " ".join(repr(x) for x in w))
        sent = w
    return w
def drain(n=None):
    k = 0
    while n is None or k < n:
        v = read()
        if v is None:
            break
        take(v)
        k += 1
    return k
def command(js):
    return [g("joint.%d.motor-pos-cmd" % j) - g("joint.%d.motor-offset" % j) for j in js]
def settle(js, slots):
    global following, sent
    # The move has ended: wait for motion to say so (in position, its queue empty) and
    # the backlash filters to reach their corrections, then take every sample up to the
    # settled command.
    # (The shell's `set_wait done` has answered while LinuxCNC still moved.)
    end = time.monotonic() + 60
    while not (g("motion.in-position") and all(g("joint.%d.backlash-filt" % j) == g("joint.%d.backlash-corr" % j) for j in js)):
        if time.monotonic() > end:
            fail("LinuxCNC's motion did not come to rest within 60 s of the move's end (motion.in-position, the backlash filters)")
            break
        time.sleep(0.001)
    target = command(js)
    drain(stream.depth)
    if following is not None:
        for _ in range(5000):
            if sent == target:
                break
            if drain(1) == 0:
                time.sleep(0.001)
        if sent != target:
            fail("the sampled command never reached the settled one %r (is the sampler on the joints' motor-pos-cmd and motor-offset?)" % target)
    following = None
    sent = None
    out("R " + " ".join(repr(x) for x in target))
buf = b""
while True:
    ready, _, _ = select.select([0], [], [], 0.002)
    if ready:
        data = os.read(0, 4096)
        if not data:
            break
        buf += data
        while b"\n" in buf:
            line, buf = buf.split(b"\n", 1)
            w = line.decode().split()
            if w and w[0] == "S":
                # from now on: the samples before are the machine at rest
                drain()
                following = [int(k) for k in w[1:]]
                sent = None
            elif w and w[0] == "E":
                settle([int(j) for j in w[1:]], following)
                failed = False
    drain()
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
        let script = format!(
            "CHANNEL = {SAMPLER_CHANNEL}\nCFG = {SAMPLER_CFG:?}\nDEPTH = {SAMPLER_DEPTH}\n{READER}"
        );
        let mut child = Command::new(HAL_PYTHON)
            .args(["-c", &script])
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
        let mut stdout = BufReader::new(
            child
                .stdout
                .take()
                .ok_or_else(|| io_error("no stdout".into()))?,
        );
        // The reader's first word: attached to the sampler's FIFO, or why not.
        let mut first = String::new();
        stdout.read_line(&mut first)?;
        if !first.starts_with("OK ") {
            let _ = child.kill();
            let _ = child.wait();
            return Err(io_error(match first.strip_prefix("X ") {
                Some(why) => why.trim_end().to_string(),
                None => "the HAL reader ended before attaching to LinuxCNC's sampler (is LinuxCNC running on this computer?)".into(),
            }));
        }
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
                if let Some(why) = line.strip_prefix("X ") {
                    failed.get_or_insert(why.to_string());
                    continue;
                }
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
    /// motor commands, every servo period.
    pub fn start(&mut self) -> std::io::Result<()> {
        // the sampler's slots of X and Y (SAMPLER_HAL wires the joints to them)
        self.request("S 0 1".into())
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

    /// The reader's process id (a test pauses it to see a lost sample caught).
    pub fn reader_id(&self) -> u32 {
        self.child.id()
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
    use super::{values, SAMPLER_CFG, SAMPLER_CHANNEL, SAMPLER_DEPTH, SAMPLER_HAL};

    #[test]
    fn the_sampler_hal_is_what_the_reader_attaches_to() {
        let load = format!("loadrt sampler depth={SAMPLER_DEPTH} cfg={SAMPLER_CFG}\n");
        assert!(SAMPLER_HAL.contains(&load), "{SAMPLER_HAL}");
        let addf = format!("addf sampler.{SAMPLER_CHANNEL} servo-thread\n");
        assert!(SAMPLER_HAL.contains(&addf), "{SAMPLER_HAL}");
        for pin in 0..SAMPLER_CFG.len() {
            let wired = format!("sampler.{SAMPLER_CHANNEL}.pin.{pin}\n");
            assert_eq!(SAMPLER_HAL.matches(&wired).count(), 1, "{wired}");
        }
    }

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
