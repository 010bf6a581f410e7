//! A fixed loopback port for one test, without colliding with anything else on the
//! machine.
//!
//! Some peers only talk to a fixed port: Aravis discovers and controls GigE Vision
//! cameras on GVCP port 3956 and nowhere else, so the interop tests must bind
//! 127.0.0.1:3956. An in-process lock keeps the tests of one binary apart, but not two
//! test processes, nor a stand-alone emulator a developer runs beside the suite: the
//! second bind fails with `AddrInUse`.
//!
//! [`on_private_loopback`] therefore runs the test body in a network namespace of its
//! own, whose loopback nobody else can see: the test re-executes its own test binary
//! (`current_exe() --exact <name> --nocapture --test-threads=1`) under `unshare -rn` (a
//! new user namespace, so no privilege is needed where the kernel allows unprivileged
//! user namespaces, plus a new network namespace), brings `lo` up there (`ip`, from
//! iproute2) and runs the body on 127.0.0.1:<port>, which is free by construction. The
//! outer test forwards the child's output and asserts that exactly that one test ran and
//! passed. As far as the port is concerned, such tests may then run in parallel.
//!
//! Where no namespace can be made (no `unshare`/`ip`, user namespaces disabled, a
//! container without the capability), it says so on stderr and falls back to the shared
//! loopback, serialised across processes by an exclusive lock on a file in the system
//! temporary directory ([`PortLock`]), so that two test processes using this module never
//! bind the port together. A foreign process holding the port then fails the test with
//! a message naming the port; see [`PortLock::acquire`] for why this fails rather than
//! skips.

use std::fs::{File, OpenOptions};
use std::net::{Ipv4Addr, UdpSocket};
use std::path::PathBuf;
use std::process::Command;
use std::sync::{Mutex, MutexGuard, OnceLock};

/// Set in the re-executed test binary: it already runs in its private namespace, so the
/// body runs directly. Its value is the test's name.
pub const INSIDE: &str = "SYSTEM_TESTS_IN_PRIVATE_NETNS";

/// Run inside the new namespace before the test binary: bring loopback up (a new
/// network namespace starts with `lo` down), then replace the shell by the command
/// (`$0 "$@"`). `ip` lives in /usr/sbin, which a non-root PATH may lack.
const BRING_UP_LO: &str = r#"PATH="$PATH:/usr/sbin:/sbin" ip link set lo up && exec "$0" "$@""#;

/// Runs `body`, the test named `test_name` (its full name as the test harness lists it,
/// e.g. `my_test` or `module::my_test`), where 127.0.0.1:`port` belongs to it alone:
/// in a private network namespace if this machine can make one, otherwise on the shared
/// loopback under [`PortLock`].
///
/// In the outer process `body` is not run when a namespace is used; the re-executed
/// binary runs the same test, whose call to this function then runs `body`. So `body`
/// must be the whole test (everything it asserts), and a test must call this once.
///
/// Panics if the child fails or if no test of that name ran in it (a wrong name).
pub fn on_private_loopback(test_name: &str, port: u16, body: impl FnOnce()) {
    if std::env::var_os(INSIDE).is_some() {
        return body();
    }
    let flags = match namespace_flags() {
        Ok(flags) => flags,
        Err(reason) => {
            eprintln!(
                "NOTE: no private network namespace here ({reason}); using the shared \
                 127.0.0.1:{port}, serialised across processes by a lock file ({})",
                PortLock::path(port).display()
            );
            let _lock = PortLock::acquire(port);
            return body();
        }
    };
    let exe = std::env::current_exe().expect("the test knows its executable");
    let out = Command::new("unshare")
        .args(flags)
        .args(["sh", "-c", BRING_UP_LO])
        .arg(&exe)
        .args(["--exact", test_name, "--include-ignored"])
        .args(["--nocapture", "--test-threads=1"])
        .env(INSIDE, test_name)
        .output()
        .expect("spawn unshare (it worked when probed)");
    let stdout = String::from_utf8_lossy(&out.stdout);
    // Through the print macros, so the harness captures it like the test's own output.
    print!("{stdout}");
    eprint!("{}", String::from_utf8_lossy(&out.stderr));
    assert!(
        out.status.success(),
        "`{test_name}` failed in its private network namespace (unshare {}: {}); its \
         output is above",
        flags.join(" "),
        out.status
    );
    // `--exact` with a name that matches nothing runs no test and still succeeds.
    assert!(
        stdout.contains("test result: ok. 1 passed"),
        "no test named `{test_name}` ran in {} (is the name passed to \
         on_private_loopback the test's full name?)",
        exe.display()
    );
}

/// The `unshare` flags that make a network namespace with loopback up on this machine,
/// or why none can be made. Probed once per process by running the very command the
/// tests use with `true` for the test binary: first `-rn` (user + network namespace,
/// unprivileged where the kernel allows it), then `-n` (enough for root outside a
/// restricted container).
pub fn namespace_flags() -> Result<&'static [&'static str], String> {
    static PROBE: OnceLock<Result<&'static [&'static str], String>> = OnceLock::new();
    PROBE
        .get_or_init(|| {
            let mut reasons = Vec::new();
            for flags in [&["-rn"][..], &["-n"][..]] {
                match Command::new("unshare")
                    .args(flags)
                    .args(["sh", "-c", BRING_UP_LO, "true"])
                    .output()
                {
                    Ok(o) if o.status.success() => return Ok(flags),
                    Ok(o) => reasons.push(format!(
                        "`unshare {} ... ip link set lo up` failed: {}",
                        flags.join(" "),
                        String::from_utf8_lossy(&o.stderr).trim()
                    )),
                    Err(e) => {
                        reasons.push(format!("`unshare` (util-linux) cannot run: {e}"));
                        break;
                    }
                }
            }
            Err(reasons.join("; "))
        })
        .clone()
}

/// Exclusive use of 127.0.0.1:`port` on a machine without private namespaces: a mutex
/// for the threads of this process, and an exclusive `flock` on
/// `<temp dir>/system-tests-loopback-<port>.lock` for other processes (two test binaries,
/// or two runs of one). The lock is released when this is dropped, or by the kernel when
/// the process dies, so a crashed test never leaves it stale. It only excludes processes
/// that take the same lock; anything else binding the port is caught by `acquire`.
pub struct PortLock {
    _file: File,
    _thread: MutexGuard<'static, ()>,
}

impl PortLock {
    /// The lock file for `port`.
    pub fn path(port: u16) -> PathBuf {
        std::env::temp_dir().join(format!("system-tests-loopback-{port}.lock"))
    }

    /// Blocks until this process holds the port's lock, then checks that
    /// 127.0.0.1:`port` is really free (UDP, as GVCP).
    ///
    /// If it is not, a process outside the lock holds it (a stand-alone emulator, a
    /// real GigE Vision tool such as `arv-fake-gv-camera-0.8`, a leftover of a killed
    /// run) and this panics naming the port and that cause. It fails rather than skips:
    /// a skip would turn the run green while the interop tests exercised nothing, and
    /// unlike a missing tool (which skips) this is a conflict the person running the
    /// tests can and should resolve; it only happens on machines that cannot make a
    /// private namespace, where the note above says so.
    pub fn acquire(port: u16) -> PortLock {
        static THREADS: Mutex<()> = Mutex::new(());
        let thread = THREADS.lock().unwrap_or_else(|p| p.into_inner());
        let path = Self::path(port);
        // Read-only suffices for flock, should another user own an existing lock file.
        let file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .or_else(|_| File::open(&path))
            .unwrap_or_else(|e| panic!("lock file {}: {e}", path.display()));
        file.lock()
            .unwrap_or_else(|e| panic!("locking {}: {e}", path.display()));
        if let Err(e) = UdpSocket::bind((Ipv4Addr::LOCALHOST, port)) {
            panic!(
                "127.0.0.1:{port} is in use by a process outside this test run ({e}): \
                 probably a stand-alone emulator or another GigE Vision device or tool \
                 (`ss -ulpn 'sport = :{port}'` shows it). Stop it, or run where a private \
                 network namespace can be made (`unshare -rn true`)."
            );
        }
        PortLock {
            _file: file,
            _thread: thread,
        }
    }
}
