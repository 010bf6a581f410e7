//! GVCP: the GigE Vision control protocol (UDP port 3956). Commands and acknowledges
//! with their 8-byte headers, encoded and decoded without I/O.

/// The well-known GVCP UDP port (discovery needs it; tests bind port 0).
pub const PORT: u16 = 3956;
/// First byte of every command packet.
pub const KEY: u8 = 0x42;
/// Command flag: the sender wants an acknowledge.
pub const FLAG_ACK_REQUIRED: u8 = 0x01;
/// DISCOVERY flag: the device may answer by broadcast.
pub const FLAG_DISCOVERY_BROADCAST_ACK: u8 = 0x10;
/// Largest READMEM/WRITEMEM data block this crate's client asks for.
pub const MAX_MEM_BLOCK: usize = 512;
/// Largest GVCP payload: a GVCP packet is at most 576 bytes with its IPv4 (20) and UDP
/// (8) headers (GigE Vision 2.x), 548 bytes of GVCP, 540 after its 8-byte header. No
/// length field beyond it is believed.
pub const MAX_PAYLOAD: usize = 540;
/// Largest READMEM count (and WRITEMEM data): the payload less the 4-byte address.
pub const MAX_READMEM: usize = MAX_PAYLOAD - 4;

pub const CMD_DISCOVERY: u16 = 0x0002;
pub const CMD_PACKETRESEND: u16 = 0x0040;
pub const CMD_READREG: u16 = 0x0080;
pub const CMD_WRITEREG: u16 = 0x0082;
pub const CMD_READMEM: u16 = 0x0084;
pub const CMD_WRITEMEM: u16 = 0x0086;
pub const ACK_PENDING: u16 = 0x0089;

/// GVCP status codes.
pub mod status {
    pub const SUCCESS: u16 = 0x0000;
    pub const NOT_IMPLEMENTED: u16 = 0x8001;
    pub const INVALID_PARAMETER: u16 = 0x8002;
    pub const INVALID_ADDRESS: u16 = 0x8003;
    pub const WRITE_PROTECT: u16 = 0x8004;
    pub const BAD_ALIGNMENT: u16 = 0x8005;
    pub const ACCESS_DENIED: u16 = 0x8006;
    pub const BUSY: u16 = 0x8007;
    pub const PACKET_UNAVAILABLE: u16 = 0x800C;
    pub const INVALID_HEADER: u16 = 0x800E;
    pub const ERROR: u16 = 0x8FFF;

    /// The status name as the standard spells it.
    pub fn name(code: u16) -> &'static str {
        match code {
            SUCCESS => "SUCCESS",
            0x0100 => "PACKET_RESEND",
            NOT_IMPLEMENTED => "NOT_IMPLEMENTED",
            INVALID_PARAMETER => "INVALID_PARAMETER",
            INVALID_ADDRESS => "INVALID_ADDRESS",
            WRITE_PROTECT => "WRITE_PROTECT",
            BAD_ALIGNMENT => "BAD_ALIGNMENT",
            ACCESS_DENIED => "ACCESS_DENIED",
            BUSY => "BUSY",
            PACKET_UNAVAILABLE => "PACKET_UNAVAILABLE",
            0x800D => "DATA_OVERRUN",
            INVALID_HEADER => "INVALID_HEADER",
            0x8010 => "PACKET_NOT_YET_AVAILABLE",
            0x8011 => "PACKET_AND_PREV_REMOVED_FROM_MEMORY",
            0x8012 => "PACKET_REMOVED_FROM_MEMORY",
            ERROR => "ERROR",
            _ => "unknown status",
        }
    }
}

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum GvcpError {
    #[error("GVCP packet of {0} bytes is shorter than its 8-byte header")]
    Short(usize),
    #[error("GVCP command key 0x{0:02X} is not 0x42")]
    BadKey(u8),
    #[error("GVCP {what}: payload length field {declared} but {got} bytes follow")]
    Length {
        what: &'static str,
        declared: usize,
        got: usize,
    },
    #[error("GVCP {what}: payload length field {declared} is more than the {max} bytes a GVCP packet holds")]
    TooLong {
        what: &'static str,
        declared: usize,
        max: usize,
    },
    #[error("GVCP {what}: malformed payload: {message}")]
    Malformed { what: &'static str, message: String },
    #[error("GVCP command 0x{0:04X} is not implemented")]
    UnknownCommand(u16),
}

/// A GVCP command (the payload of a command packet).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Command {
    Discovery,
    ReadReg(Vec<u32>),
    WriteReg(Vec<(u32, u32)>),
    ReadMem {
        address: u32,
        count: u16,
    },
    WriteMem {
        address: u32,
        data: Vec<u8>,
    },
    /// Ask the device to send GVSP packets `first..=last` of `block_id` again.
    PacketResend {
        channel: u16,
        block_id: u16,
        first: u32,
        last: u32,
    },
}

impl Command {
    pub fn code(&self) -> u16 {
        match self {
            Command::Discovery => CMD_DISCOVERY,
            Command::ReadReg(_) => CMD_READREG,
            Command::WriteReg(_) => CMD_WRITEREG,
            Command::ReadMem { .. } => CMD_READMEM,
            Command::WriteMem { .. } => CMD_WRITEMEM,
            Command::PacketResend { .. } => CMD_PACKETRESEND,
        }
    }

    /// Short human name for errors ("READREG 0x0A00").
    pub fn describe(&self) -> String {
        match self {
            Command::Discovery => "DISCOVERY".into(),
            Command::ReadReg(a) => format!("READREG {}", hex_list(a.iter().copied())),
            Command::WriteReg(w) => format!("WRITEREG {}", hex_list(w.iter().map(|p| p.0))),
            Command::ReadMem { address, count } => {
                format!("READMEM 0x{address:08X} ({count} bytes)")
            }
            Command::WriteMem { address, data } => {
                format!("WRITEMEM 0x{address:08X} ({} bytes)", data.len())
            }
            Command::PacketResend {
                block_id,
                first,
                last,
                ..
            } => format!("PACKETRESEND block {block_id} packets {first}..={last}"),
        }
    }
}

fn hex_list(a: impl Iterator<Item = u32>) -> String {
    a.map(|x| format!("0x{x:04X}"))
        .collect::<Vec<_>>()
        .join(",")
}

/// A command packet: header flags, request id and command.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CommandPacket {
    pub flags: u8,
    pub req_id: u16,
    pub command: Command,
}

impl CommandPacket {
    pub fn encode(&self) -> Vec<u8> {
        let mut body = Vec::new();
        match &self.command {
            Command::Discovery => {}
            Command::ReadReg(addrs) => addrs.iter().for_each(|a| put32(&mut body, *a)),
            Command::WriteReg(w) => w.iter().for_each(|(a, v)| {
                put32(&mut body, *a);
                put32(&mut body, *v);
            }),
            Command::ReadMem { address, count } => {
                put32(&mut body, *address);
                put16(&mut body, 0);
                put16(&mut body, *count);
            }
            Command::WriteMem { address, data } => {
                put32(&mut body, *address);
                body.extend_from_slice(data);
            }
            Command::PacketResend {
                channel,
                block_id,
                first,
                last,
            } => {
                put16(&mut body, *channel);
                put16(&mut body, *block_id);
                put32(&mut body, first & 0x00FF_FFFF);
                put32(&mut body, last & 0x00FF_FFFF);
            }
        }
        let mut out = Vec::with_capacity(8 + body.len());
        out.push(KEY);
        out.push(self.flags);
        put16(&mut out, self.command.code());
        put16(&mut out, body.len() as u16);
        put16(&mut out, self.req_id);
        out.extend_from_slice(&body);
        out
    }

    pub fn decode(b: &[u8]) -> Result<Self, GvcpError> {
        if b.len() < 8 {
            return Err(GvcpError::Short(b.len()));
        }
        if b[0] != KEY {
            return Err(GvcpError::BadKey(b[0]));
        }
        let flags = b[1];
        let code = get16(b, 2);
        let len = get16(b, 4) as usize;
        let req_id = get16(b, 6);
        let p = &b[8..];
        let what = "command";
        check_length(what, len)?;
        if p.len() < len {
            return Err(GvcpError::Length {
                what,
                declared: len,
                got: p.len(),
            });
        }
        let p = &p[..len];
        let malformed = |m: &str| GvcpError::Malformed {
            what,
            message: m.to_string(),
        };
        let command = match code {
            CMD_DISCOVERY => Command::Discovery,
            CMD_READREG => {
                if p.is_empty() || p.len() & 3 != 0 {
                    return Err(malformed("READREG needs a multiple of 4 bytes"));
                }
                Command::ReadReg(p.chunks(4).map(|c| get32(c, 0)).collect())
            }
            CMD_WRITEREG => {
                if p.is_empty() || p.len() & 7 != 0 {
                    return Err(malformed("WRITEREG needs address/value pairs"));
                }
                Command::WriteReg(p.chunks(8).map(|c| (get32(c, 0), get32(c, 4))).collect())
            }
            CMD_READMEM => {
                if p.len() != 8 {
                    return Err(malformed("READMEM needs 8 bytes"));
                }
                let count = get16(p, 6);
                if count as usize > MAX_READMEM {
                    return Err(malformed(&format!(
                        "READMEM count {count} is more than the {MAX_READMEM} bytes an ack holds"
                    )));
                }
                Command::ReadMem {
                    address: get32(p, 0),
                    count: get16(p, 6),
                }
            }
            CMD_WRITEMEM => {
                if p.len() < 4 {
                    return Err(malformed("WRITEMEM needs an address"));
                }
                Command::WriteMem {
                    address: get32(p, 0),
                    data: p[4..].to_vec(),
                }
            }
            CMD_PACKETRESEND => {
                if p.len() < 12 {
                    return Err(malformed("PACKETRESEND needs 12 bytes"));
                }
                Command::PacketResend {
                    channel: get16(p, 0),
                    block_id: get16(p, 2),
                    first: get32(p, 4) & 0x00FF_FFFF,
                    last: get32(p, 8) & 0x00FF_FFFF,
                }
            }
            other => return Err(GvcpError::UnknownCommand(other)),
        };
        Ok(Self {
            flags,
            req_id,
            command,
        })
    }
}

/// What an acknowledge carries (by ack code).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum AckBody {
    /// The bootstrap registers 0x0000-0x00F7.
    Discovery(Vec<u8>),
    ReadReg(Vec<u32>),
    /// Index of the last register written (or of the failing one).
    WriteReg {
        index: u16,
    },
    ReadMem {
        address: u32,
        data: Vec<u8>,
    },
    WriteMem {
        index: u16,
    },
    /// The device needs `ms` more milliseconds; the real ack follows.
    Pending {
        ms: u16,
    },
    /// An error ack's payload or an ack code this codec does not know.
    Other {
        code: u16,
        payload: Vec<u8>,
    },
}

#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Ack {
    pub status: u16,
    pub ack_id: u16,
    pub body: AckBody,
}

impl Ack {
    pub fn ack_code(&self) -> u16 {
        match &self.body {
            AckBody::Discovery(_) => CMD_DISCOVERY + 1,
            AckBody::ReadReg(_) => CMD_READREG + 1,
            AckBody::WriteReg { .. } => CMD_WRITEREG + 1,
            AckBody::ReadMem { .. } => CMD_READMEM + 1,
            AckBody::WriteMem { .. } => CMD_WRITEMEM + 1,
            AckBody::Pending { .. } => ACK_PENDING,
            AckBody::Other { code, .. } => *code,
        }
    }

    /// An error acknowledge to `command` (no payload, the command's ack code).
    pub fn error(command: u16, status: u16, ack_id: u16) -> Self {
        Self {
            status,
            ack_id,
            body: AckBody::Other {
                code: command + 1,
                payload: Vec::new(),
            },
        }
    }

    pub fn encode(&self) -> Vec<u8> {
        let mut body = Vec::new();
        match &self.body {
            AckBody::Discovery(d) => body.extend_from_slice(d),
            AckBody::ReadReg(v) => v.iter().for_each(|x| put32(&mut body, *x)),
            AckBody::WriteReg { index } | AckBody::WriteMem { index } => {
                put16(&mut body, 0);
                put16(&mut body, *index);
            }
            AckBody::ReadMem { address, data } => {
                put32(&mut body, *address);
                body.extend_from_slice(data);
            }
            AckBody::Pending { ms } => {
                put16(&mut body, 0);
                put16(&mut body, *ms);
            }
            AckBody::Other { payload, .. } => body.extend_from_slice(payload),
        }
        let mut out = Vec::with_capacity(8 + body.len());
        put16(&mut out, self.status);
        put16(&mut out, self.ack_code());
        put16(&mut out, body.len() as u16);
        put16(&mut out, self.ack_id);
        out.extend_from_slice(&body);
        out
    }

    pub fn decode(b: &[u8]) -> Result<Self, GvcpError> {
        if b.len() < 8 {
            return Err(GvcpError::Short(b.len()));
        }
        let status = get16(b, 0);
        let code = get16(b, 2);
        let len = get16(b, 4) as usize;
        let ack_id = get16(b, 6);
        let p = &b[8..];
        check_length("ack", len)?;
        if p.len() < len {
            return Err(GvcpError::Length {
                what: "ack",
                declared: len,
                got: p.len(),
            });
        }
        let p = &p[..len];
        let other = || AckBody::Other {
            code,
            payload: p.to_vec(),
        };
        let body = if status != status::SUCCESS && code != ACK_PENDING {
            other()
        } else {
            match code {
                c if c == CMD_DISCOVERY + 1 => AckBody::Discovery(p.to_vec()),
                c if c == CMD_READREG + 1 && p.len() & 3 == 0 => {
                    AckBody::ReadReg(p.chunks(4).map(|c| get32(c, 0)).collect())
                }
                c if c == CMD_WRITEREG + 1 && p.len() >= 4 => {
                    AckBody::WriteReg { index: get16(p, 2) }
                }
                c if c == CMD_READMEM + 1 && p.len() >= 4 => AckBody::ReadMem {
                    address: get32(p, 0),
                    data: p[4..].to_vec(),
                },
                c if c == CMD_WRITEMEM + 1 && p.len() >= 4 => {
                    AckBody::WriteMem { index: get16(p, 2) }
                }
                ACK_PENDING if p.len() >= 4 => AckBody::Pending { ms: get16(p, 2) },
                _ => other(),
            }
        };
        Ok(Self {
            status,
            ack_id,
            body,
        })
    }
}

/// A payload length field against [`MAX_PAYLOAD`].
fn check_length(what: &'static str, declared: usize) -> Result<(), GvcpError> {
    if declared > MAX_PAYLOAD {
        return Err(GvcpError::TooLong {
            what,
            declared,
            max: MAX_PAYLOAD,
        });
    }
    Ok(())
}

pub(crate) fn put16(o: &mut Vec<u8>, v: u16) {
    o.extend_from_slice(&v.to_be_bytes());
}
pub(crate) fn put32(o: &mut Vec<u8>, v: u32) {
    o.extend_from_slice(&v.to_be_bytes());
}
pub(crate) fn get16(b: &[u8], i: usize) -> u16 {
    u16::from_be_bytes([b[i], b[i + 1]])
}
pub(crate) fn get32(b: &[u8], i: usize) -> u32 {
    u32::from_be_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn readreg_bytes_match_the_standard() {
        let p = CommandPacket {
            flags: FLAG_ACK_REQUIRED,
            req_id: 7,
            command: Command::ReadReg(vec![0x0A00]),
        };
        let b = p.encode();
        assert_eq!(b, [0x42, 1, 0, 0x80, 0, 4, 0, 7, 0, 0, 0x0A, 0]);
        assert_eq!(CommandPacket::decode(&b).unwrap(), p);
    }

    #[test]
    fn commands_round_trip() {
        for c in [
            Command::Discovery,
            Command::WriteReg(vec![(0x0A00, 2), (0x0D00, 5000)]),
            Command::ReadMem {
                address: 0x10000,
                count: 512,
            },
            Command::WriteMem {
                address: 0x20000,
                data: vec![1, 2, 3, 4],
            },
            Command::PacketResend {
                channel: 0,
                block_id: 9,
                first: 3,
                last: 5,
            },
        ] {
            let p = CommandPacket {
                flags: 1,
                req_id: 0xFFFF,
                command: c,
            };
            assert_eq!(CommandPacket::decode(&p.encode()).unwrap(), p);
        }
    }

    #[test]
    fn acks_round_trip_and_errors_keep_their_status() {
        for a in [
            Ack {
                status: 0,
                ack_id: 3,
                body: AckBody::ReadReg(vec![2, 3]),
            },
            Ack {
                status: 0,
                ack_id: 3,
                body: AckBody::ReadMem {
                    address: 0x200,
                    data: b"Local:x.xml;0;4\0".to_vec(),
                },
            },
            Ack {
                status: 0,
                ack_id: 4,
                body: AckBody::WriteReg { index: 1 },
            },
            Ack {
                status: 0,
                ack_id: 4,
                body: AckBody::Pending { ms: 200 },
            },
            Ack::error(CMD_WRITEREG, status::ACCESS_DENIED, 5),
        ] {
            assert_eq!(Ack::decode(&a.encode()).unwrap(), a);
        }
    }

    #[test]
    fn short_and_lying_packets_are_refused() {
        assert_eq!(
            CommandPacket::decode(&[0x42, 1, 0]),
            Err(GvcpError::Short(3))
        );
        assert_eq!(
            CommandPacket::decode(&[0x41, 1, 0, 0x80, 0, 0, 0, 1]),
            Err(GvcpError::BadKey(0x41))
        );
        assert!(matches!(
            CommandPacket::decode(&[0x42, 1, 0, 0x80, 0, 8, 0, 1, 0, 0, 0, 0]),
            Err(GvcpError::Length { .. })
        ));
    }

    #[test]
    fn lengths_beyond_the_protocol_maxima_are_refused() {
        // A length field that the datagram backs, but no GVCP packet can be that long.
        let mut big = vec![0, 0, 0, 0x85, 0x02, 0x58, 0, 1];
        big.extend(vec![0u8; 600]);
        let e = Ack::decode(&big).map(|_| ()).unwrap_err();
        assert_eq!(
            e.to_string(),
            "GVCP ack: payload length field 600 is more than the 540 bytes a GVCP packet holds"
        );
        let mut cmd = vec![0x42, 1, 0, 0x86, 0x02, 0x58, 0, 1];
        cmd.extend(vec![0u8; 600]);
        assert!(matches!(
            CommandPacket::decode(&cmd),
            Err(GvcpError::TooLong { declared: 600, .. })
        ));
        // READMEM asks for at most 536 bytes (what fits a READMEM ack).
        let e =
            CommandPacket::decode(&[0x42, 1, 0, 0x84, 0, 8, 0, 1, 0, 0, 0, 0, 0, 0, 0xFF, 0xFF])
                .unwrap_err();
        assert!(e.to_string().contains("READMEM count 65535"), "{e}");
        // The largest legal packets still decode.
        let a = Ack {
            status: 0,
            ack_id: 1,
            body: AckBody::ReadMem {
                address: 0,
                data: vec![7; MAX_READMEM],
            },
        };
        assert_eq!(Ack::decode(&a.encode()).unwrap(), a);
    }
}
