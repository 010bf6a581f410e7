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
//! The follower is told when to follow (after each move has ended, after homing), so
//! the simulated machine moves once per LinuxCNC move, along the same direction: its
//! backlash and every other simulated error act as on a stage driven by that motor
//! command. LinuxCNC must run on this computer (HAL is shared memory).

use std::io::{BufRead, BufReader, Write};
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};
use world::{lock, SharedRig};

/// Debian's python3 with LinuxCNC's `hal` module (package `python3-linuxcnc`, which
/// `linuxcnc-uspace` depends on).
pub const HAL_PYTHON: &str = "/usr/bin/python3";

/// Per request line (the joint numbers), once each joint's backlash filter has reached
/// its correction (the motor command has settled), `motor-pos-cmd - motor-offset` of
/// those joints.
const READER: &str = r#"
import hal, os, sys, time
c = hal.component("xygw_rig_follower_%d" % os.getpid())
g = hal.get_value
for line in sys.stdin:
    joints = [int(j) for j in line.split()]
    for _ in range(5000):
        if all(g("joint.%d.backlash-filt" % j) == g("joint.%d.backlash-corr" % j) for j in joints):
            break
        time.sleep(0.001)
    print(" ".join(repr(g("joint.%d.motor-pos-cmd" % j) - g("joint.%d.motor-offset" % j)) for j in joints), flush=True)
c.exit()
"#;

/// HAL's joint pins of the LinuxCNC running on this computer.
pub struct HalJoints {
    child: Child,
    /// Closed on drop: the reader then removes its HAL component and ends.
    stdin: Option<ChildStdin>,
    stdout: BufReader<ChildStdout>,
}

fn io_error(message: String) -> std::io::Error {
    std::io::Error::other(message)
}

impl HalJoints {
    pub fn start() -> std::io::Result<HalJoints> {
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
        Ok(HalJoints {
            child,
            stdin: Some(stdin),
            stdout,
        })
    }

    /// `joint.N.motor-pos-cmd - joint.N.motor-offset` of `joints`, settled, in machine
    /// units: the motor command from where LinuxCNC last homed.
    pub fn motor_pos_cmd(&mut self, joints: &[u8]) -> std::io::Result<Vec<f64>> {
        let request: Vec<String> = joints.iter().map(|j| j.to_string()).collect();
        let stdin = self
            .stdin
            .as_mut()
            .ok_or_else(|| io_error("the HAL reader is closed".into()))?;
        writeln!(stdin, "{}", request.join(" "))?;
        stdin.flush()?;
        let mut line = String::new();
        // Bounded: one short line (a few numbers) per request.
        if self.stdout.read_line(&mut line)? == 0 {
            return Err(io_error(
                "the HAL reader ended (is LinuxCNC running on this computer?)".into(),
            ));
        }
        let values: Option<Vec<f64>> = line
            .split_whitespace()
            .map(|w| w.parse::<f64>().ok().filter(|v| v.is_finite()))
            .collect();
        match values {
            Some(v) if v.len() == joints.len() => Ok(v),
            _ => Err(io_error(format!(
                "the HAL reader said {}",
                protocol::text::escape_bytes(line.as_bytes())
            ))),
        }
    }
}

impl Drop for HalJoints {
    fn drop(&mut self) {
        // End of input: the reader leaves HAL cleanly (`c.exit()`); a killed one would
        // leave its component behind. Killed only if it has not ended within 2 s.
        drop(self.stdin.take());
        for _ in 0..200 {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            std::thread::sleep(std::time::Duration::from_millis(10));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The simulated stage (X and Y of the rig's machine) slaved to two LinuxCNC joints.
pub struct LinuxcncFollower {
    rig: SharedRig,
    hal: HalJoints,
    /// The joints of X and Y.
    joints: [u8; 2],
}

impl LinuxcncFollower {
    pub fn new(rig: SharedRig, joints: [u8; 2]) -> std::io::Result<Self> {
        Ok(Self {
            rig,
            hal: HalJoints::start()?,
            joints,
        })
    }

    /// LinuxCNC has homed: the simulated machine homes (a new homing error), then goes
    /// where the joints are commanded.
    pub fn homed(&mut self, feed_mm_min: f64) -> std::io::Result<[f64; 2]> {
        lock(&self.rig).machine_mut().home();
        self.follow(feed_mm_min)
    }

    /// Move the simulated machine to the joints' motor commands (a move of LinuxCNC has
    /// ended). Returns them. Nothing moves while the simulated machine is not homed.
    pub fn follow(&mut self, feed_mm_min: f64) -> std::io::Result<[f64; 2]> {
        let v = self.hal.motor_pos_cmd(&self.joints)?;
        let target = [v[0], v[1]];
        let mut rig = lock(&self.rig);
        let m = rig.machine_mut();
        if m.is_homed() {
            m.start_move(target, feed_mm_min).map_err(|e| {
                io_error(format!(
                    "the simulated stage cannot follow LinuxCNC to {target:?}: {e}"
                ))
            })?;
            m.finish_motion();
        }
        Ok(target)
    }
}
