//! A man in the middle of a TCP link (Modbus TCP), for the fault matrix: the driver
//! connects here, the bytes go on to the device, and one fault ([`SerialFault`], each
//! read one message) strikes after so many requests. A kill closes both connections and
//! refuses new ones (the device is gone).

use crate::faulty_serial::SerialFault;
use std::io;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::task::JoinHandle;

pub struct FaultyTcp {
    addr: SocketAddr,
    fired: Arc<AtomicBool>,
    task: JoinHandle<()>,
}

impl FaultyTcp {
    /// Listen on a loopback port, forwarding every connection to `device`.
    pub async fn spawn(device: SocketAddr, fault: SerialFault) -> io::Result<FaultyTcp> {
        let listener = TcpListener::bind(("127.0.0.1", 0)).await?;
        let addr = listener.local_addr()?;
        let fired = Arc::new(AtomicBool::new(false));
        let flag = fired.clone();
        let task = tokio::spawn(async move {
            let mut requests = 0usize;
            loop {
                let Ok((host, _)) = listener.accept().await else {
                    return;
                };
                if flag.load(Ordering::SeqCst) && matches!(fault, SerialFault::Kill { .. }) {
                    // The device is gone: connections are refused (closed at once).
                    drop(host);
                    continue;
                }
                let Ok(dev) = TcpStream::connect(device).await else {
                    return;
                };
                if !relay(host, dev, fault, &flag, &mut requests).await {
                    // Killed: keep refusing.
                    continue;
                }
            }
        });
        Ok(FaultyTcp { addr, fired, task })
    }

    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    pub fn fired(&self) -> bool {
        self.fired.load(Ordering::SeqCst)
    }
}

impl Drop for FaultyTcp {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// Relay one connection until either side closes; false when the fault killed it.
async fn relay(
    mut host: TcpStream,
    mut dev: TcpStream,
    fault: SerialFault,
    fired: &AtomicBool,
    requests: &mut usize,
) -> bool {
    let mut from_host = [0u8; 4096];
    let mut from_dev = [0u8; 4096];
    let mut armed = false;
    let after = match fault {
        SerialFault::Kill { after }
        | SerialFault::Stall { after, .. }
        | SerialFault::DropReply { after }
        | SerialFault::CorruptReply { after }
        | SerialFault::LateReply { after, .. }
        | SerialFault::Inject { after, .. } => after,
    };
    loop {
        tokio::select! {
            r = host.read(&mut from_host) => {
                let Ok(n) = r else { return true };
                if n == 0 || dev.write_all(&from_host[..n]).await.is_err() {
                    return true;
                }
                *requests += 1;
                if !armed && !fired.load(Ordering::SeqCst) && *requests >= after {
                    match fault {
                        SerialFault::Kill { .. } => {
                            fired.store(true, Ordering::SeqCst);
                            return false;
                        }
                        SerialFault::Stall { duration, .. } => {
                            fired.store(true, Ordering::SeqCst);
                            tokio::time::sleep(duration).await;
                        }
                        SerialFault::Inject { bytes, .. } => {
                            fired.store(true, Ordering::SeqCst);
                            if dev.write_all(bytes).await.is_err() {
                                return true;
                            }
                        }
                        _ => armed = true,
                    }
                }
            }
            r = dev.read(&mut from_dev) => {
                let Ok(n) = r else { return true };
                if n == 0 {
                    return true;
                }
                let mut reply = from_dev[..n].to_vec();
                if armed {
                    armed = false;
                    fired.store(true, Ordering::SeqCst);
                    match fault {
                        SerialFault::DropReply { .. } => reply.clear(),
                        // The transaction id's low byte: the reply no longer matches.
                        SerialFault::CorruptReply { .. } => reply[1] ^= 0x5A,
                        SerialFault::LateReply { delay, .. } => tokio::time::sleep(delay).await,
                        _ => {}
                    }
                }
                if host.write_all(&reply).await.is_err() {
                    return true;
                }
            }
        }
    }
}
