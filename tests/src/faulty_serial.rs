//! A man in the middle of a serial link, for the fault matrix: the driver opens this
//! pseudo-terminal, the bytes go on to the device's port, and one fault is injected at a
//! known point of the exchange (after so many messages from the host): the device
//! killed, stalled then resumed, a reply lost, late or corrupted.
//!
//! The stall and the late reply wait inside this link (that is the device's behaviour
//! being simulated); the tests themselves never wait on wall time.

use std::io;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::task::JoinHandle;
use tokio_serial::{SerialPort, SerialPortBuilderExt, SerialStream};

/// How messages are delimited on the link.
#[derive(Clone, Copy, Debug)]
pub enum Framing {
    /// Text lines ending with this byte (GRBL `\n`, SLCAN `\r`).
    Lines(u8),
    /// Each read is one message (Modbus RTU frames arrive whole on a pty).
    Chunks,
}

/// The fault, and after how many host messages it strikes.
#[derive(Clone, Copy, Debug)]
pub enum SerialFault {
    /// Both ports closed (the device powered off, the cable pulled).
    Kill { after: usize },
    /// Nothing passes either way for `duration`, then everything held goes on.
    Stall { after: usize, duration: Duration },
    /// The device's next message is lost.
    DropReply { after: usize },
    /// One byte of the device's next message is changed.
    CorruptReply { after: usize },
    /// The device's next message comes `delay` late.
    LateReply { after: usize, delay: Duration },
    /// These bytes reach the device as if from the host (an operator's command from a
    /// second sender, a pendant: a way to make the device itself raise an alarm).
    Inject { after: usize, bytes: &'static [u8] },
}

impl SerialFault {
    fn after(&self) -> usize {
        match *self {
            SerialFault::Kill { after }
            | SerialFault::Stall { after, .. }
            | SerialFault::DropReply { after }
            | SerialFault::CorruptReply { after }
            | SerialFault::LateReply { after, .. }
            | SerialFault::Inject { after, .. } => after,
        }
    }
}

/// The link; dropping it stops it.
pub struct FaultySerial {
    path: String,
    fired: Arc<AtomicBool>,
    sent: Arc<std::sync::Mutex<Vec<u8>>>,
    task: JoinHandle<()>,
}

impl FaultySerial {
    /// A new pseudo-terminal for the driver, forwarding to `device` (inside a runtime).
    pub fn spawn(device: &str, framing: Framing, fault: SerialFault) -> io::Result<FaultySerial> {
        let (host, slave) = SerialStream::pair().map_err(|e| io::Error::other(e.to_string()))?;
        let path = slave
            .name()
            .ok_or_else(|| io::Error::other("the pseudo-terminal has no slave path"))?;
        let dev = tokio_serial::new(device, 115_200)
            .open_native_async()
            .map_err(|e| io::Error::other(e.to_string()))?;
        let fired = Arc::new(AtomicBool::new(false));
        let sent = Arc::new(std::sync::Mutex::new(Vec::new()));
        let task = tokio::spawn(run(
            host,
            slave,
            dev,
            framing,
            fault,
            fired.clone(),
            sent.clone(),
        ));
        Ok(FaultySerial {
            path,
            fired,
            sent,
            task,
        })
    }

    /// The port the driver opens.
    pub fn path(&self) -> &str {
        &self.path
    }

    /// Every byte the host sent through the link, in order.
    pub fn host_bytes(&self) -> Vec<u8> {
        self.sent.lock().unwrap_or_else(|p| p.into_inner()).clone()
    }

    /// Whether the fault struck.
    pub fn fired(&self) -> bool {
        self.fired.load(Ordering::SeqCst)
    }
}

impl Drop for FaultySerial {
    fn drop(&mut self) {
        self.task.abort();
    }
}

async fn run(
    mut host: SerialStream,
    slave: SerialStream,
    mut dev: SerialStream,
    framing: Framing,
    fault: SerialFault,
    fired: Arc<AtomicBool>,
    sent: Arc<std::sync::Mutex<Vec<u8>>>,
) {
    // The slave stays open here until a kill, so the host side never reads a hang-up
    // between the driver's opening and closing of the port.
    let mut slave = Some(slave);
    let mut from_host = [0u8; 4096];
    let mut from_dev = [0u8; 4096];
    let mut host_messages = 0usize;
    let mut armed = false;
    let mut pending_reply = Vec::new();
    loop {
        tokio::select! {
            r = host.read(&mut from_host) => {
                let Ok(n) = r else { return };
                if n == 0 {
                    return;
                }
                let bytes = &from_host[..n];
                sent.lock().unwrap_or_else(|p| p.into_inner()).extend_from_slice(bytes);
                host_messages += match framing {
                    Framing::Lines(end) => bytes.iter().filter(|&&b| b == end).count(),
                    Framing::Chunks => 1,
                };
                if dev.write_all(bytes).await.is_err() {
                    return;
                }
                if !armed && !fired.load(Ordering::SeqCst) && host_messages >= fault.after() {
                    match fault {
                        SerialFault::Kill { .. } => {
                            fired.store(true, Ordering::SeqCst);
                            drop(slave.take());
                            return;
                        }
                        SerialFault::Stall { duration, .. } => {
                            fired.store(true, Ordering::SeqCst);
                            tokio::time::sleep(duration).await;
                        }
                        SerialFault::Inject { bytes, .. } => {
                            fired.store(true, Ordering::SeqCst);
                            if dev.write_all(bytes).await.is_err() {
                                return;
                            }
                        }
                        _ => armed = true,
                    }
                }
            }
            r = dev.read(&mut from_dev) => {
                let Ok(n) = r else { return };
                if n == 0 {
                    return;
                }
                let mut bytes = from_dev[..n].to_vec();
                if armed {
                    // Collect the whole next message, then apply the fault to it.
                    pending_reply.extend_from_slice(&bytes);
                    let complete = match framing {
                        Framing::Lines(end) => pending_reply.iter().position(|&b| b == end),
                        Framing::Chunks => Some(pending_reply.len() - 1),
                    };
                    let Some(end) = complete else { continue };
                    let rest = pending_reply.split_off(end + 1);
                    let mut message = std::mem::take(&mut pending_reply);
                    armed = false;
                    fired.store(true, Ordering::SeqCst);
                    match fault {
                        SerialFault::DropReply { .. } => message.clear(),
                        SerialFault::CorruptReply { .. } => {
                            // The first byte of a line (an `o` of `ok` becomes `p`), the
                            // last of a binary frame (its CRC).
                            let k = match framing {
                                Framing::Lines(_) => 0,
                                Framing::Chunks => message.len() - 1,
                            };
                            message[k] ^= 0x1F;
                        }
                        SerialFault::LateReply { delay, .. } => tokio::time::sleep(delay).await,
                        _ => {}
                    }
                    message.extend_from_slice(&rest);
                    bytes = message;
                }
                if host.write_all(&bytes).await.is_err() {
                    return;
                }
            }
        }
    }
}
