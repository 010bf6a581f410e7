//! The GVCP client: one request at a time on a UDP socket, each under a deadline with
//! bounded retries (as Aravis: 500 ms x a few), acks matched by id, PENDING_ACK
//! honoured, error statuses turned into `Refused` naming the command.

use crate::error::DriverError;
use protocol::gige::gvcp::{self, status, Ack, AckBody, Command, CommandPacket};
use std::net::SocketAddr;
use std::time::Duration;
use tokio::net::UdpSocket;

pub struct Gvcp {
    pub(crate) sock: UdpSocket,
    pub(crate) peer: SocketAddr,
    req_id: u16,
    pub timeout: Duration,
    pub retries: u32,
    pub(crate) device: String,
}

impl Gvcp {
    pub async fn connect(
        peer: SocketAddr,
        timeout: Duration,
        retries: u32,
    ) -> Result<Self, DriverError> {
        let device = format!("GigE Vision camera at {peer}");
        let local: SocketAddr = if peer.ip().is_loopback() {
            "127.0.0.1:0".parse().expect("literal")
        } else {
            "0.0.0.0:0".parse().expect("literal")
        };
        let sock = UdpSocket::bind(local)
            .await
            .map_err(|e| DriverError::Transport {
                device: device.clone(),
                message: format!("binding the control socket: {e}"),
            })?;
        Ok(Self {
            sock,
            peer,
            req_id: 0,
            timeout,
            retries,
            device,
        })
    }

    fn next_id(&mut self) -> u16 {
        self.req_id = if self.req_id == u16::MAX {
            1
        } else {
            self.req_id + 1
        };
        self.req_id
    }

    /// Sends `command` and returns its successful ack.
    pub async fn request(&mut self, command: Command) -> Result<AckBody, DriverError> {
        let what = command.describe();
        let id = self.next_id();
        let bytes = CommandPacket {
            flags: gvcp::FLAG_ACK_REQUIRED,
            req_id: id,
            command,
        }
        .encode();
        let mut buf = vec![0u8; 1024];
        for _attempt in 0..=self.retries {
            self.sock
                .send_to(&bytes, self.peer)
                .await
                .map_err(|e| DriverError::Transport {
                    device: self.device.clone(),
                    message: format!("sending {what}: {e}"),
                })?;
            let mut deadline = tokio::time::Instant::now() + self.timeout;
            loop {
                let r = tokio::time::timeout_at(deadline, self.sock.recv_from(&mut buf)).await;
                let Ok(r) = r else { break };
                let (n, from) = r.map_err(|e| DriverError::Transport {
                    device: self.device.clone(),
                    message: format!("receiving the ack to {what}: {e}"),
                })?;
                if from.ip() != self.peer.ip() {
                    continue;
                }
                let Ok(ack) = Ack::decode(&buf[..n]) else {
                    continue;
                };
                if ack.ack_id != id {
                    // A late ack to an earlier, retried request.
                    continue;
                }
                if let AckBody::Pending { ms } = ack.body {
                    deadline = tokio::time::Instant::now()
                        + Duration::from_millis(ms as u64)
                        + self.timeout;
                    continue;
                }
                if ack.status != status::SUCCESS {
                    return Err(DriverError::Refused {
                        device: self.device.clone(),
                        what,
                        code: ack.status as u32,
                        message: format!(
                            "GVCP status 0x{:04X} {}",
                            ack.status,
                            status::name(ack.status)
                        ),
                    });
                }
                return Ok(ack.body);
            }
        }
        Err(DriverError::Timeout {
            device: self.device.clone(),
            what,
            after_ms: self.timeout.as_millis() as u64 * (self.retries as u64 + 1),
        })
    }

    pub async fn read_reg(&mut self, addr: u32) -> Result<u32, DriverError> {
        match self.request(Command::ReadReg(vec![addr])).await? {
            AckBody::ReadReg(v) if v.len() == 1 => Ok(v[0]),
            other => Err(self.violation(format!("READREG 0x{addr:04X} answered with {other:?}"))),
        }
    }

    pub async fn write_reg(&mut self, addr: u32, value: u32) -> Result<(), DriverError> {
        self.request(Command::WriteReg(vec![(addr, value)]))
            .await
            .map(|_| ())
    }

    /// Reads `len` bytes (split into 512-byte READMEMs rounded up to 4), at most
    /// [`protocol::gige::MAX_XML_SIZE`] and inside the 32-bit address space: lengths
    /// come from the camera (URL register, GenICam XML).
    pub async fn read_mem(&mut self, addr: u32, len: usize) -> Result<Vec<u8>, DriverError> {
        let max = protocol::gige::MAX_XML_SIZE;
        if len > max {
            return Err(self.violation(format!(
                "READMEM 0x{addr:08X}: {len} bytes asked, more than the {max} bytes this driver reads from a camera"
            )));
        }
        let last = u32::try_from(len.div_ceil(4) * 4)
            .ok()
            .and_then(|n| addr.checked_add(n.saturating_sub(1)));
        if len > 0 && last.is_none() {
            return Err(self.violation(format!(
                "READMEM 0x{addr:08X}: {len} bytes run past the end of the 32-bit address space"
            )));
        }
        let mut out = Vec::with_capacity(len);
        while out.len() < len {
            // Inside the address space: checked above.
            let at = addr.wrapping_add(out.len() as u32);
            let n = (len - out.len()).min(gvcp::MAX_MEM_BLOCK).div_ceil(4) * 4;
            match self
                .request(Command::ReadMem {
                    address: at,
                    count: n as u16,
                })
                .await?
            {
                AckBody::ReadMem { address, data } if address == at && data.len() == n => {
                    out.extend_from_slice(&data)
                }
                other => {
                    return Err(
                        self.violation(format!("READMEM 0x{at:08X} answered with {other:?}"))
                    )
                }
            }
        }
        out.truncate(len);
        Ok(out)
    }

    pub async fn write_mem(&mut self, addr: u32, data: Vec<u8>) -> Result<(), DriverError> {
        self.request(Command::WriteMem {
            address: addr,
            data,
        })
        .await
        .map(|_| ())
    }

    /// PACKETRESEND (no acknowledge).
    pub async fn packet_resend(
        &mut self,
        block_id: u16,
        first: u32,
        last: u32,
    ) -> Result<(), DriverError> {
        let id = self.next_id();
        let bytes = CommandPacket {
            flags: 0,
            req_id: id,
            command: Command::PacketResend {
                channel: 0,
                block_id,
                first,
                last,
            },
        }
        .encode();
        self.sock
            .send_to(&bytes, self.peer)
            .await
            .map(|_| ())
            .map_err(|e| DriverError::Transport {
                device: self.device.clone(),
                message: format!("sending PACKETRESEND: {e}"),
            })
    }

    pub(crate) fn violation(&self, message: String) -> DriverError {
        DriverError::Protocol {
            device: self.device.clone(),
            message,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A peer that never answers: a read that reached the network would time out.
    async fn silent() -> (UdpSocket, Gvcp) {
        let peer = UdpSocket::bind("127.0.0.1:0").await.unwrap();
        let c = Gvcp::connect(peer.local_addr().unwrap(), Duration::from_millis(50), 0)
            .await
            .unwrap();
        (peer, c)
    }

    #[tokio::test]
    async fn read_lengths_from_the_camera_are_bounded_before_reading() {
        let (_peer, mut c) = silent().await;
        let e = c
            .read_mem(0x8000, 0xFFFF_FFFF)
            .await
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("4294967295 bytes asked, more than the 16777216 bytes"),
            "{e}"
        );
        let e = c
            .read_mem(0xFFFF_FF00, 0x200)
            .await
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("past the end of the 32-bit address space"),
            "{e}"
        );
        // The last word of the address space is still readable (times out here).
        let e = c.read_mem(0xFFFF_FFFC, 4).await.unwrap_err();
        assert!(matches!(e, DriverError::Timeout { .. }), "{e}");
    }
}
