//! An emulated CAN bus with several SLCAN adapters plugged into it, each on its own
//! pseudo-terminal: a frame one host transmits reaches every other host whose channel
//! is open, as on a real bus with several USB adapters. It lets two independent CANopen
//! stacks meet (the gateway's driver on one port, a python-canopen node on another)
//! with no kernel CAN support.

use super::pty::SlcanAdapter;
use protocol::can::CanFrame;
use std::io;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::broadcast;
use tokio::task::JoinHandle;
use tokio_serial::{SerialPort, SerialStream};

/// A running hub; dropping it unplugs every adapter.
pub struct SlcanHub {
    paths: Vec<String>,
    tasks: Vec<JoinHandle<()>>,
}

impl SlcanHub {
    /// `n` adapters on one bus, each on a new pseudo-terminal (inside a tokio runtime).
    pub fn spawn(n: usize) -> io::Result<SlcanHub> {
        let (bus, _) = broadcast::channel::<(usize, CanFrame)>(4096);
        let mut paths = Vec::new();
        let mut tasks = Vec::new();
        for k in 0..n {
            let (master, slave) =
                SerialStream::pair().map_err(|e| io::Error::other(e.to_string()))?;
            paths.push(
                slave
                    .name()
                    .ok_or_else(|| io::Error::other("the pseudo-terminal has no slave path"))?,
            );
            tasks.push(tokio::spawn(serve(k, master, slave, bus.clone())));
        }
        Ok(SlcanHub { paths, tasks })
    }

    /// The adapters' slave paths (`/dev/pts/N`), one per port.
    pub fn paths(&self) -> &[String] {
        &self.paths
    }
}

impl Drop for SlcanHub {
    fn drop(&mut self) {
        for t in &self.tasks {
            t.abort();
        }
    }
}

async fn serve(
    me: usize,
    mut master: SerialStream,
    slave: SerialStream,
    bus: broadcast::Sender<(usize, CanFrame)>,
) {
    let mut rx = bus.subscribe();
    let mut adapter = SlcanAdapter::default();
    let mut buf = [0u8; 4096];
    let t0 = std::time::Instant::now();
    loop {
        let mut out = Vec::new();
        tokio::select! {
            r = master.read(&mut buf) => match r {
                Ok(n) if n > 0 => {
                    let mut frames = Vec::new();
                    adapter.host_bytes(&buf[..n], &mut frames, &mut out);
                    for f in frames {
                        let _ = bus.send((me, f));
                    }
                }
                _ => break,
            },
            m = rx.recv() => match m {
                Ok((from, f)) if from != me => adapter.bus_frame(&f, t0.elapsed().as_millis() as u64, &mut out),
                Ok(_) => {}
                // A slow reader lost frames, as an adapter whose FIFO overflowed does.
                Err(broadcast::error::RecvError::Lagged(_)) => {}
                Err(broadcast::error::RecvError::Closed) => break,
            },
        }
        if !out.is_empty() && master.write_all(&out).await.is_err() {
            break;
        }
    }
    drop(slave);
}
