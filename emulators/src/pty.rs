//! A device served on a pseudo-terminal: the lifecycle every serial emulator shares
//! (the GRBL controller, the SLCAN adapter, the Modbus RTU line).
//!
//! The runner holds the slave side open itself, so clients may come and go without the
//! master seeing a hang-up; [`PtyPort::hang_up`] closes both sides, which is what a
//! client sees when a USB adapter is unplugged.

use std::future::Future;
use std::io;
use std::path::{Path, PathBuf};
use tokio::sync::oneshot;
use tokio::task::JoinHandle;
use tokio_serial::{SerialPort, SerialStream};

/// A running device on a pseudo-terminal. Dropping it stops the device.
pub struct PtyPort {
    path: String,
    link: Option<PathBuf>,
    stop: Option<oneshot::Sender<()>>,
    task: Option<JoinHandle<()>>,
}

impl PtyPort {
    /// Create a pseudo-terminal and spawn `serve(master, slave, stop)` on it (inside a
    /// tokio runtime); `serve` returns when `stop` fires. With `link`, a symlink to the
    /// slave path is made there (replacing an old one), so clients can use a stable name.
    pub fn spawn<F, Fut>(link: Option<&Path>, serve: F) -> io::Result<PtyPort>
    where
        F: FnOnce(SerialStream, SerialStream, oneshot::Receiver<()>) -> Fut,
        Fut: Future<Output = ()> + Send + 'static,
    {
        // The slave side stays without any lock (no flock, no TIOCEXCL), so clients may
        // open it exclusively as they do real ports.
        let (master, slave) = SerialStream::pair().map_err(|e| io::Error::other(e.to_string()))?;
        let path = slave
            .name()
            .ok_or_else(|| io::Error::other("the pseudo-terminal has no slave path"))?;
        if let Some(l) = link {
            if l.symlink_metadata().is_ok() {
                std::fs::remove_file(l)?;
            }
            std::os::unix::fs::symlink(&path, l)?;
        }
        let (tx, rx) = oneshot::channel();
        let task = tokio::spawn(serve(master, slave, rx));
        Ok(PtyPort {
            path,
            link: link.map(Path::to_path_buf),
            stop: Some(tx),
            task: Some(task),
        })
    }

    /// The slave path (`/dev/pts/N`) clients open.
    pub fn path(&self) -> &str {
        &self.path
    }

    /// The symlink, if one was asked for.
    pub fn link(&self) -> Option<&Path> {
        self.link.as_deref()
    }

    /// Close the pseudo-terminal: the port disappears for its client. The symlink stays
    /// (a replugged adapter gets the same name back).
    pub async fn hang_up(mut self) {
        if let Some(tx) = self.stop.take() {
            let _ = tx.send(());
        }
        if let Some(t) = self.task.take() {
            let _ = t.await;
        }
    }

    /// Wait until the device ends by itself (or is stopped).
    pub async fn closed(&mut self) {
        if let Some(t) = self.task.take() {
            let _ = t.await;
        }
    }
}

impl Drop for PtyPort {
    fn drop(&mut self) {
        if let Some(tx) = self.stop.take() {
            let _ = tx.send(());
        }
    }
}
