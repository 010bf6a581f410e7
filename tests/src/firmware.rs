//! Real controller firmware as a test peer: GRBL 1.1h (grbl-sim) and grblHAL (its host
//! simulator, 3 or 6 axes), built from `../shared/peers` by `tests/firmware/build.sh`
//! and attached to a pseudo-terminal with `socat`, each in its own working directory
//! (its EEPROM file lives there: a new directory is a first power-up, which prints
//! `error:7`, the settings dump, then the banner).
//!
//! The pty is created with socat's `wait-slave`: the firmware is started only when the
//! test first opens the tty, so the opener reads everything the firmware prints from
//! power-up on (as a sender does when an Arduino resets on DTR). Closing the tty ends
//! the firmware's link: open it once per start.
//!
//! A firmware that cannot be built, or a missing `socat`, is an `Err` naming the
//! install step; tests `expect` it, so they fail (never skip) on a machine without the
//! peers.

use std::fs::File;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// What to run when a firmware peer is missing.
pub const INSTALL_STEP: &str =
    "run tests/install-peers.sh (it builds the firmwares with tests/firmware/build.sh and installs socat, cmake, gcc, make)";

/// A real firmware the tests can start.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Firmware {
    /// gnea/grbl 1.1h with grbl-sim (3 axes).
    Grbl11h,
    /// grblHAL with its host simulator, 3 axes (X Y Z).
    GrblHal3,
    /// grblHAL with its host simulator, 6 axes (X Y Z A B C).
    GrblHal6,
}

/// How to start a firmware (see [`Firmware::start_with`]).
#[derive(Clone, Debug, Default)]
pub struct StartOptions {
    /// The working directory (its EEPROM file); `None`: a fresh temporary one (a first
    /// power-up).
    pub workdir: Option<PathBuf>,
    /// grbl_sim's `-t`: the simulated clock runs this many times the wall clock
    /// (GRBL 1.1h only; grblHAL runs in real time). `None`: real time.
    pub time_factor: Option<f64>,
}

/// Where `tests/firmware/build.sh` puts the builds: `$GRBL_FIRMWARE_DIR`, or
/// `target/firmware` in the workspace.
pub fn firmware_dir() -> PathBuf {
    match std::env::var_os("GRBL_FIRMWARE_DIR") {
        Some(d) => PathBuf::from(d),
        None => crate::workspace().join("target").join("firmware"),
    }
}

impl Firmware {
    /// The name `tests/firmware/build.sh` knows it by (and its folder under the
    /// firmware dir).
    pub fn name(self) -> &'static str {
        match self {
            Firmware::Grbl11h => "grbl11h",
            Firmware::GrblHal3 => "grblhal3",
            Firmware::GrblHal6 => "grblhal6",
        }
    }

    fn relative_binary(self) -> &'static str {
        match self {
            Firmware::Grbl11h => "grbl/grbl-sim/grbl_sim.exe",
            Firmware::GrblHal3 | Firmware::GrblHal6 => "build/grblHAL_sim",
        }
    }

    /// The built binary, built first by `tests/firmware/build.sh` when it is missing or
    /// stale (GRBL 1.1h built before the harness's current limit-switch patch: the
    /// script knows by its stamp, and returns at once when nothing is to be built).
    pub fn binary(self) -> Result<PathBuf, String> {
        let dir = firmware_dir();
        let bin = dir.join(self.name()).join(self.relative_binary());
        let script = crate::workspace().join("tests/firmware/build.sh");
        let out = Command::new("bash")
            .arg(&script)
            .arg(&dir)
            .arg(self.name())
            .stdin(Stdio::null())
            .output()
            .map_err(|e| format!("cannot run {}: {e}; {INSTALL_STEP}", script.display()))?;
        if !out.status.success() || !bin.exists() {
            return Err(format!(
                "the {} firmware is missing or stale and building it failed: {}; {INSTALL_STEP}",
                self.name(),
                String::from_utf8_lossy(&out.stderr).trim()
            ));
        }
        Ok(bin)
    }

    /// Start it in a fresh working directory: a first power-up.
    pub fn start(self) -> Result<RunningFirmware, String> {
        self.start_with(StartOptions::default())
    }

    /// Start it in `workdir`, reusing the EEPROM file an earlier run left there (not a
    /// first power-up when there is one).
    pub fn start_in(self, workdir: &Path) -> Result<RunningFirmware, String> {
        self.start_with(StartOptions {
            workdir: Some(workdir.to_path_buf()),
            ..Default::default()
        })
    }

    /// Start it with `opts`: attach it to a pty with socat and wait (a bounded number of
    /// polls) until the pty's link exists.
    pub fn start_with(self, opts: StartOptions) -> Result<RunningFirmware, String> {
        let bin = self.binary()?;
        if which("socat").is_none() {
            return Err(format!(
                "socat is missing (Debian: apt-get install -y socat); {INSTALL_STEP}"
            ));
        }
        let (workdir, tmp) = match opts.workdir {
            Some(d) => {
                std::fs::create_dir_all(&d)
                    .map_err(|e| format!("cannot create {}: {e}", d.display()))?;
                (d, None)
            }
            None => {
                let t = tempfile::Builder::new()
                    .prefix(&format!("fw-{}-", self.name()))
                    .tempdir()
                    .map_err(|e| format!("cannot create a working directory: {e}"))?;
                (t.path().to_path_buf(), Some(t))
            }
        };
        let tty = workdir.join("tty");
        let block_log = workdir.join("blocks");
        let socat_log = workdir.join("socat.log");
        let _ = std::fs::remove_file(&tty);
        let _ = std::fs::remove_file(&block_log);
        let mut args = vec!["-n".to_string(), "-b".into(), shell_path(&block_log)];
        let program = match self {
            Firmware::Grbl11h => {
                if let Some(t) = opts.time_factor {
                    args.push("-t".into());
                    args.push(format!("{t}"));
                }
                args.push("-s".into());
                args.push("/dev/null".into());
                format!("stdbuf -i0 {}", shell_path(&bin))
            }
            Firmware::GrblHal3 | Firmware::GrblHal6 => shell_path(&bin),
        };
        let exec = format!("EXEC:'{} {}',pty,raw,echo=0", program, args.join(" "));
        let pty = format!("PTY,raw,echo=0,wait-slave,link={}", tty.display());
        let log = File::create(&socat_log)
            .map_err(|e| format!("cannot create {}: {e}", socat_log.display()))?;
        let mut cmd = Command::new("socat");
        cmd.args(["-d", "-d", &pty, &exec])
            .current_dir(&workdir)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(log);
        {
            use std::os::unix::process::CommandExt;
            cmd.process_group(0);
        }
        let child = cmd
            .spawn()
            .map_err(|e| format!("cannot start socat: {e}; {INSTALL_STEP}"))?;
        let mut running = RunningFirmware {
            firmware: self,
            tty,
            block_log,
            workdir,
            socat_log,
            socat: child,
            _tmp: tmp,
        };
        // Bounded: 1000 polls of 10 ms; socat creates the link at once.
        for _ in 0..1000 {
            if running.tty.exists() {
                return Ok(running);
            }
            if let Ok(Some(status)) = running.socat.try_wait() {
                return Err(format!(
                    "socat ended ({status}) before creating {}: {}",
                    running.tty.display(),
                    std::fs::read_to_string(&running.socat_log).unwrap_or_default()
                ));
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        Err(format!(
            "socat did not create {} (log: {})",
            running.tty.display(),
            std::fs::read_to_string(&running.socat_log).unwrap_or_default()
        ))
    }
}

/// A firmware running on a pty; everything is killed when dropped.
pub struct RunningFirmware {
    pub firmware: Firmware,
    /// The pty link to open (once).
    pub tty: PathBuf,
    /// The firmware's log of every planned block (`-b`).
    pub block_log: PathBuf,
    /// The working directory (EEPROM file, logs); reuse it with [`Firmware::start_in`].
    pub workdir: PathBuf,
    socat_log: PathBuf,
    socat: Child,
    _tmp: Option<tempfile::TempDir>,
}

impl RunningFirmware {
    /// The tty path as a string (for the driver's `open`).
    pub fn path(&self) -> String {
        self.tty.display().to_string()
    }

    /// The block log so far.
    pub fn blocks(&self) -> String {
        std::fs::read_to_string(&self.block_log).unwrap_or_default()
    }

    /// Open the tty for plain byte I/O (the first open starts the firmware).
    pub fn open(&self) -> Result<TtyClient, String> {
        TtyClient::open(&self.tty)
    }

    /// Open the tty and keep it open without reading it: the firmware keeps running
    /// while other clients open and close the port one after another (as a controller
    /// whose USB adapter does not reset it on DTR). The first open powers it up; what
    /// it prints waits for the next reader. Dropping the file lets it go.
    pub fn hold(&self) -> Result<File, String> {
        std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .open(&self.tty)
            .map_err(|e| format!("cannot open {}: {e}", self.tty.display()))
    }

    /// The firmware's process id, from socat's log (once the tty has been opened).
    fn firmware_pid(&self) -> Option<u32> {
        let log = std::fs::read_to_string(&self.socat_log).ok()?;
        log.lines()
            .filter_map(|l| l.split("forked off child process ").nth(1))
            .filter_map(|p| p.trim().parse().ok())
            .next()
    }

    /// Keep the working directory (its EEPROM file) after the firmware ends, for
    /// [`Firmware::start_in`]; returns its path.
    pub fn keep_workdir(&mut self) -> PathBuf {
        if let Some(t) = self._tmp.take() {
            let _ = t.keep();
        }
        self.workdir.clone()
    }
}

impl Drop for RunningFirmware {
    fn drop(&mut self) {
        // grblHAL_sim ignores SIGTERM: SIGKILL, by process id and process group only.
        if let Some(pid) = self.firmware_pid() {
            let _ = Command::new("kill")
                .args(["-KILL", &pid.to_string()])
                .stderr(Stdio::null())
                .status();
        }
        let pg = format!("-{}", self.socat.id());
        let _ = Command::new("kill")
            .args(["-KILL", "--", &pg])
            .stderr(Stdio::null())
            .status();
        let _ = self.socat.kill();
        let _ = self.socat.wait();
    }
}

/// A plain byte client of a tty (the firmware's or the emulator's): bytes out, and
/// the bytes that came back, read by a thread so that every wait is bounded.
pub struct TtyClient {
    file: File,
    rx: mpsc::Receiver<Vec<u8>>,
    /// Bytes received and not yet taken.
    pub pending: Vec<u8>,
}

impl TtyClient {
    /// Open `path` read-write (the pty is already raw: socat and the emulator set it).
    pub fn open(path: &Path) -> Result<TtyClient, String> {
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .open(path)
            .map_err(|e| format!("cannot open {}: {e}", path.display()))?;
        let mut reader = file
            .try_clone()
            .map_err(|e| format!("cannot clone {}: {e}", path.display()))?;
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            let mut buf = [0u8; 4096];
            loop {
                match reader.read(&mut buf) {
                    Ok(0) | Err(_) => break,
                    Ok(n) => {
                        if tx.send(buf[..n].to_vec()).is_err() {
                            break;
                        }
                    }
                }
            }
        });
        Ok(TtyClient {
            file,
            rx,
            pending: Vec::new(),
        })
    }

    pub fn send(&mut self, bytes: &[u8]) {
        self.file.write_all(bytes).expect("write to the tty");
        let _ = self.file.flush();
    }

    /// Wait until `done(received)` says the answer is complete, then take and return
    /// everything received. Bounded by `limit`: a missing answer is an `Err` with what
    /// did arrive (never a timing assertion: the bound only ends a broken test).
    pub fn read_until(
        &mut self,
        limit: Duration,
        mut done: impl FnMut(&[u8]) -> bool,
    ) -> Result<Vec<u8>, String> {
        let end = Instant::now() + limit;
        while !done(&self.pending) {
            let left = end.saturating_duration_since(Instant::now());
            match self.rx.recv_timeout(left) {
                Ok(b) => self.pending.extend_from_slice(&b),
                Err(e) => {
                    return Err(format!(
                        "no complete answer ({e}); received: {:?}",
                        String::from_utf8_lossy(&self.pending)
                    ))
                }
            }
        }
        Ok(std::mem::take(&mut self.pending))
    }

    /// Wait for a line satisfying `line_done` (a line ends in `\n`); returns
    /// everything received up to and including that line, leaving the rest pending.
    pub fn read_through_line(
        &mut self,
        limit: Duration,
        mut line_done: impl FnMut(&str) -> bool,
    ) -> Result<String, String> {
        let end = Instant::now() + limit;
        loop {
            let mut start = 0;
            for (i, &b) in self.pending.iter().enumerate() {
                if b == b'\n' {
                    let line = String::from_utf8_lossy(&self.pending[start..i]);
                    if line_done(line.trim_end_matches('\r')) {
                        let rest = self.pending.split_off(i + 1);
                        let got = std::mem::replace(&mut self.pending, rest);
                        return Ok(String::from_utf8_lossy(&got).into_owned());
                    }
                    start = i + 1;
                }
            }
            let left = end.saturating_duration_since(Instant::now());
            match self.rx.recv_timeout(left) {
                Ok(b) => self.pending.extend_from_slice(&b),
                Err(e) => {
                    return Err(format!(
                        "no matching line ({e}); received: {:?}",
                        String::from_utf8_lossy(&self.pending)
                    ))
                }
            }
        }
    }
}

fn which(program: &str) -> Option<PathBuf> {
    std::env::var_os("PATH").and_then(|paths| {
        std::env::split_paths(&paths)
            .map(|p| p.join(program))
            .find(|p| p.is_file())
    })
}

/// A path inside socat's single-quoted EXEC string.
fn shell_path(p: &Path) -> String {
    p.display().to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_match_the_build_script() {
        let script = std::fs::read_to_string(crate::workspace().join("tests/firmware/build.sh"))
            .expect("tests/firmware/build.sh");
        for fw in [Firmware::Grbl11h, Firmware::GrblHal3, Firmware::GrblHal6] {
            assert!(script.contains(fw.name()), "{}", fw.name());
            assert!(
                script.contains(fw.relative_binary()),
                "{}",
                fw.relative_binary()
            );
        }
    }
}
