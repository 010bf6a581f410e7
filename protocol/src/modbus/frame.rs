//! Modbus application data units as bytes (Modbus Application Protocol V1.1b3 and
//! Modbus over Serial Line V1.02): the PDUs of the functions positioning drives use,
//! exception responses, the RTU frame (unit id, PDU, CRC-16 low byte first) and the
//! TCP MBAP header. The emulator frames with this (so it can drop, delay or corrupt
//! exactly one reply); the driver uses it to explain garbled replies.

use std::fmt;

/// Function codes this crate knows.
pub mod function {
    pub const READ_COILS: u8 = 0x01;
    pub const READ_DISCRETE_INPUTS: u8 = 0x02;
    pub const READ_HOLDING_REGISTERS: u8 = 0x03;
    pub const READ_INPUT_REGISTERS: u8 = 0x04;
    pub const WRITE_SINGLE_COIL: u8 = 0x05;
    pub const WRITE_SINGLE_REGISTER: u8 = 0x06;
    pub const WRITE_MULTIPLE_COILS: u8 = 0x0F;
    pub const WRITE_MULTIPLE_REGISTERS: u8 = 0x10;
    pub const MASK_WRITE_REGISTER: u8 = 0x16;
    pub const READ_WRITE_MULTIPLE_REGISTERS: u8 = 0x17;
}

/// Most registers one read may ask for (spec: 125) and one write may carry (123).
pub const MAX_READ: u16 = 125;
pub const MAX_WRITE: u16 = 123;

/// Exception codes of the Modbus application protocol.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Exception {
    IllegalFunction,
    IllegalDataAddress,
    IllegalDataValue,
    ServerDeviceFailure,
    Acknowledge,
    ServerDeviceBusy,
    GatewayPathUnavailable,
    GatewayTargetFailed,
    Other(u8),
}

impl Exception {
    pub fn code(self) -> u8 {
        match self {
            Exception::IllegalFunction => 0x01,
            Exception::IllegalDataAddress => 0x02,
            Exception::IllegalDataValue => 0x03,
            Exception::ServerDeviceFailure => 0x04,
            Exception::Acknowledge => 0x05,
            Exception::ServerDeviceBusy => 0x06,
            Exception::GatewayPathUnavailable => 0x0A,
            Exception::GatewayTargetFailed => 0x0B,
            Exception::Other(c) => c,
        }
    }

    pub fn from_code(c: u8) -> Self {
        match c {
            0x01 => Exception::IllegalFunction,
            0x02 => Exception::IllegalDataAddress,
            0x03 => Exception::IllegalDataValue,
            0x04 => Exception::ServerDeviceFailure,
            0x05 => Exception::Acknowledge,
            0x06 => Exception::ServerDeviceBusy,
            0x0A => Exception::GatewayPathUnavailable,
            0x0B => Exception::GatewayTargetFailed,
            c => Exception::Other(c),
        }
    }

    /// The specification's name of the code.
    pub fn name(self) -> &'static str {
        match self {
            Exception::IllegalFunction => "illegal function",
            Exception::IllegalDataAddress => "illegal data address",
            Exception::IllegalDataValue => "illegal data value",
            Exception::ServerDeviceFailure => "server device failure",
            Exception::Acknowledge => "acknowledge",
            Exception::ServerDeviceBusy => "server device busy",
            Exception::GatewayPathUnavailable => "gateway path unavailable",
            Exception::GatewayTargetFailed => "gateway target device failed to respond",
            Exception::Other(_) => "exception",
        }
    }
}

impl fmt::Display for Exception {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "exception {:02X} ({})", self.code(), self.name())
    }
}

/// A request PDU.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Request {
    ReadHolding {
        address: u16,
        count: u16,
    },
    ReadInput {
        address: u16,
        count: u16,
    },
    WriteSingle {
        address: u16,
        value: u16,
    },
    WriteMultiple {
        address: u16,
        values: Vec<u16>,
    },
    /// Any other function, with its data bytes (answered with an exception).
    Other {
        function: u8,
        data: Vec<u8>,
    },
}

impl Request {
    pub fn function(&self) -> u8 {
        match self {
            Request::ReadHolding { .. } => function::READ_HOLDING_REGISTERS,
            Request::ReadInput { .. } => function::READ_INPUT_REGISTERS,
            Request::WriteSingle { .. } => function::WRITE_SINGLE_REGISTER,
            Request::WriteMultiple { .. } => function::WRITE_MULTIPLE_REGISTERS,
            Request::Other { function, .. } => *function,
        }
    }

    pub fn encode(&self) -> Vec<u8> {
        let mut out = vec![self.function()];
        match self {
            Request::ReadHolding { address, count } | Request::ReadInput { address, count } => {
                out.extend(address.to_be_bytes());
                out.extend(count.to_be_bytes());
            }
            Request::WriteSingle { address, value } => {
                out.extend(address.to_be_bytes());
                out.extend(value.to_be_bytes());
            }
            Request::WriteMultiple { address, values } => {
                out.extend(address.to_be_bytes());
                out.extend((values.len() as u16).to_be_bytes());
                out.push((values.len() * 2) as u8);
                for v in values {
                    out.extend(v.to_be_bytes());
                }
            }
            Request::Other { data, .. } => out.extend(data),
        }
        out
    }

    /// Parse a request PDU as a server does: an unknown function is kept as `Other`
    /// (the server answers "illegal function"); a malformed or out-of-range quantity
    /// is `IllegalDataValue`, as the specification's state diagrams say.
    pub fn parse(pdu: &[u8]) -> Result<Request, (u8, Exception)> {
        let Some(&f) = pdu.first() else {
            return Err((0, Exception::IllegalFunction));
        };
        let bad = Err((f, Exception::IllegalDataValue));
        let u16_at = |i: usize| u16::from_be_bytes([pdu[i], pdu[i + 1]]);
        match f {
            function::READ_HOLDING_REGISTERS | function::READ_INPUT_REGISTERS => {
                if pdu.len() != 5 {
                    return bad;
                }
                let (address, count) = (u16_at(1), u16_at(3));
                if count == 0 || count > MAX_READ {
                    return bad;
                }
                Ok(if f == function::READ_HOLDING_REGISTERS {
                    Request::ReadHolding { address, count }
                } else {
                    Request::ReadInput { address, count }
                })
            }
            function::WRITE_SINGLE_REGISTER => {
                if pdu.len() != 5 {
                    return bad;
                }
                Ok(Request::WriteSingle {
                    address: u16_at(1),
                    value: u16_at(3),
                })
            }
            function::WRITE_MULTIPLE_REGISTERS => {
                if pdu.len() < 6 {
                    return bad;
                }
                let (address, count, bytes) = (u16_at(1), u16_at(3), pdu[5] as usize);
                if count == 0 || count > MAX_WRITE || bytes != 2 * count as usize {
                    return bad;
                }
                if pdu.len() != 6 + bytes {
                    return bad;
                }
                let values = (0..count as usize).map(|k| u16_at(6 + 2 * k)).collect();
                Ok(Request::WriteMultiple { address, values })
            }
            _ => Ok(Request::Other {
                function: f,
                data: pdu[1..].to_vec(),
            }),
        }
    }
}

/// A response PDU.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Response {
    /// Registers read (function 3 or 4).
    Registers {
        function: u8,
        values: Vec<u16>,
    },
    /// Echo of a single-register write.
    WroteSingle {
        address: u16,
        value: u16,
    },
    /// Address and quantity of a multiple-register write.
    WroteMultiple {
        address: u16,
        count: u16,
    },
    Exception {
        function: u8,
        exception: Exception,
    },
}

impl Response {
    pub fn encode(&self) -> Vec<u8> {
        match self {
            Response::Registers { function, values } => {
                let mut out = vec![*function, (values.len() * 2) as u8];
                for v in values {
                    out.extend(v.to_be_bytes());
                }
                out
            }
            Response::WroteSingle { address, value } => {
                let mut out = vec![function::WRITE_SINGLE_REGISTER];
                out.extend(address.to_be_bytes());
                out.extend(value.to_be_bytes());
                out
            }
            Response::WroteMultiple { address, count } => {
                let mut out = vec![function::WRITE_MULTIPLE_REGISTERS];
                out.extend(address.to_be_bytes());
                out.extend(count.to_be_bytes());
                out
            }
            Response::Exception {
                function,
                exception,
            } => {
                vec![function | 0x80, exception.code()]
            }
        }
    }

    /// Parse a response PDU (for tests and diagnostics; the driver's client is
    /// tokio-modbus).
    pub fn parse(pdu: &[u8]) -> Option<Response> {
        let f = *pdu.first()?;
        let u16_at = |i: usize| u16::from_be_bytes([pdu[i], pdu[i + 1]]);
        if f & 0x80 != 0 {
            return (pdu.len() == 2).then(|| Response::Exception {
                function: f & 0x7F,
                exception: Exception::from_code(pdu[1]),
            });
        }
        match f {
            function::READ_HOLDING_REGISTERS | function::READ_INPUT_REGISTERS => {
                let n = *pdu.get(1)? as usize;
                if pdu.len() != 2 + n || !n.is_multiple_of(2) {
                    return None;
                }
                let values = (0..n / 2).map(|k| u16_at(2 + 2 * k)).collect();
                Some(Response::Registers {
                    function: f,
                    values,
                })
            }
            function::WRITE_SINGLE_REGISTER if pdu.len() == 5 => Some(Response::WroteSingle {
                address: u16_at(1),
                value: u16_at(3),
            }),
            function::WRITE_MULTIPLE_REGISTERS if pdu.len() == 5 => Some(Response::WroteMultiple {
                address: u16_at(1),
                count: u16_at(3),
            }),
            _ => None,
        }
    }
}

/// CRC-16/MODBUS (polynomial 0xA001 reflected, initial 0xFFFF).
pub fn crc16(data: &[u8]) -> u16 {
    let mut crc: u16 = 0xFFFF;
    for &b in data {
        crc ^= b as u16;
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0xA001
            } else {
                crc >> 1
            };
        }
    }
    crc
}

/// An RTU frame: unit id, PDU, CRC (low byte first).
pub fn rtu_frame(unit: u8, pdu: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(pdu.len() + 3);
    out.push(unit);
    out.extend_from_slice(pdu);
    let crc = crc16(&out);
    out.extend(crc.to_le_bytes());
    out
}

/// Whether a complete RTU frame's CRC is right.
pub fn rtu_crc_ok(frame: &[u8]) -> bool {
    frame.len() >= 4 && {
        let (body, crc) = frame.split_at(frame.len() - 2);
        crc16(body).to_le_bytes() == [crc[0], crc[1]]
    }
}

/// How much of a byte buffer an RTU frame takes, judged from its function code.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameLen {
    /// Not enough bytes yet to know.
    NeedMore,
    /// The frame is this many bytes long (unit, PDU, CRC).
    Bytes(usize),
    /// The function code gives no length: resynchronise.
    Unknown,
}

/// Length of the RTU *request* frame at the start of `buf` (as a server sees it).
pub fn rtu_request_len(buf: &[u8]) -> FrameLen {
    let Some(&f) = buf.get(1) else {
        return FrameLen::NeedMore;
    };
    match f {
        0x01..=0x06 => FrameLen::Bytes(8),
        0x07 | 0x0B | 0x0C | 0x11 => FrameLen::Bytes(4),
        0x0F | 0x10 => match buf.get(6) {
            Some(&n) => FrameLen::Bytes(9 + n as usize),
            None => FrameLen::NeedMore,
        },
        0x16 => FrameLen::Bytes(10),
        0x17 => match buf.get(10) {
            Some(&n) => FrameLen::Bytes(13 + n as usize),
            None => FrameLen::NeedMore,
        },
        _ => FrameLen::Unknown,
    }
}

/// Length of the RTU *response* frame at the start of `buf` (as a client sees it).
pub fn rtu_response_len(buf: &[u8]) -> FrameLen {
    let Some(&f) = buf.get(1) else {
        return FrameLen::NeedMore;
    };
    match f {
        0x01..=0x04 | 0x0C | 0x11 | 0x17 => match buf.get(2) {
            Some(&n) => FrameLen::Bytes(5 + n as usize),
            None => FrameLen::NeedMore,
        },
        0x05 | 0x06 | 0x0B | 0x0F | 0x10 => FrameLen::Bytes(8),
        0x07 => FrameLen::Bytes(5),
        0x16 => FrameLen::Bytes(10),
        0x81..=0xAB => FrameLen::Bytes(5),
        _ => FrameLen::Unknown,
    }
}

/// The MBAP header of Modbus TCP: transaction id, protocol id (0), length of what
/// follows (unit id + PDU), unit id.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Mbap {
    pub transaction: u16,
    pub protocol: u16,
    pub length: u16,
    pub unit: u8,
}

impl Mbap {
    pub const LEN: usize = 7;

    pub fn parse(b: &[u8]) -> Option<Mbap> {
        (b.len() >= Self::LEN).then(|| Mbap {
            transaction: u16::from_be_bytes([b[0], b[1]]),
            protocol: u16::from_be_bytes([b[2], b[3]]),
            length: u16::from_be_bytes([b[4], b[5]]),
            unit: b[6],
        })
    }

    /// A whole TCP ADU: header for `pdu`, then the PDU.
    pub fn frame(transaction: u16, unit: u8, pdu: &[u8]) -> Vec<u8> {
        let mut out = Vec::with_capacity(Self::LEN + pdu.len());
        out.extend(transaction.to_be_bytes());
        out.extend(0u16.to_be_bytes());
        out.extend(((pdu.len() + 1) as u16).to_be_bytes());
        out.push(unit);
        out.extend_from_slice(pdu);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn leadshine_manual_example_frame_has_the_printed_crc() {
        // Leadshine ELD2-RS manual: PR0 absolute move, 100000 pulses, 500 rpm, slave 17.
        let pdu = Request::WriteMultiple {
            address: 0x6200,
            values: vec![
                0x0001, 0x0001, 0x86A0, 0x01F4, 0x0064, 0x0064, 0x0000, 0x0010,
            ],
        }
        .encode();
        let frame = rtu_frame(0x11, &pdu);
        let expect = [
            0x11, 0x10, 0x62, 0x00, 0x00, 0x08, 0x10, 0x00, 0x01, 0x00, 0x01, 0x86, 0xA0, 0x01,
            0xF4, 0x00, 0x64, 0x00, 0x64, 0x00, 0x00, 0x00, 0x10, 0x67, 0xB3,
        ];
        assert_eq!(frame, expect);
        assert!(rtu_crc_ok(&frame));
        assert_eq!(rtu_request_len(&frame), FrameLen::Bytes(frame.len()));
    }

    #[test]
    fn well_known_read_request_crc() {
        // 01 03 00 00 00 0A C5 CD: the classic "read 10 holding registers" frame.
        let f = rtu_frame(
            1,
            &Request::ReadHolding {
                address: 0,
                count: 10,
            }
            .encode(),
        );
        assert_eq!(f, [0x01, 0x03, 0x00, 0x00, 0x00, 0x0A, 0xC5, 0xCD]);
    }

    #[test]
    fn requests_round_trip_and_bad_quantities_are_illegal_values() {
        for r in [
            Request::ReadHolding {
                address: 0x7E,
                count: 2,
            },
            Request::ReadInput {
                address: 1,
                count: 125,
            },
            Request::WriteSingle {
                address: 0x7D,
                value: 0x10,
            },
            Request::WriteMultiple {
                address: 0x58,
                values: (0..16).collect(),
            },
        ] {
            assert_eq!(Request::parse(&r.encode()), Ok(r));
        }
        let too_many = Request::ReadHolding {
            address: 0,
            count: 126,
        }
        .encode();
        assert_eq!(
            Request::parse(&too_many),
            Err((3, Exception::IllegalDataValue))
        );
        let mut wrong_count = Request::WriteMultiple {
            address: 0,
            values: vec![1, 2],
        }
        .encode();
        wrong_count[5] = 3;
        assert_eq!(
            Request::parse(&wrong_count),
            Err((0x10, Exception::IllegalDataValue))
        );
        assert!(matches!(
            Request::parse(&[0x2B, 0x0E, 1, 0]),
            Ok(Request::Other { function: 0x2B, .. })
        ));
    }

    #[test]
    fn responses_round_trip() {
        for r in [
            Response::Registers {
                function: 3,
                values: vec![1, 0xFFFF],
            },
            Response::WroteSingle {
                address: 7,
                value: 9,
            },
            Response::WroteMultiple {
                address: 0x6200,
                count: 8,
            },
            Response::Exception {
                function: 3,
                exception: Exception::IllegalDataAddress,
            },
        ] {
            assert_eq!(Response::parse(&r.encode()), Some(r));
        }
        let ex = rtu_frame(1, &[0x83, 0x02]);
        assert_eq!(rtu_response_len(&ex), FrameLen::Bytes(5));
    }

    #[test]
    fn mbap_header() {
        let f = Mbap::frame(0x1234, 0xFF, &[3, 0, 0, 0, 1]);
        let h = Mbap::parse(&f).unwrap();
        assert_eq!(
            (h.transaction, h.protocol, h.length, h.unit),
            (0x1234, 0, 6, 0xFF)
        );
    }
}
