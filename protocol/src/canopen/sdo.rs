//! Service data objects: the client (master) and server (node) state machines for
//! expedited and segmented upload and download, with CiA 301 abort codes.
//!
//! Frames are always 8 bytes: byte 0 the command specifier, bytes 1-2 the index (LE),
//! byte 3 the subindex, bytes 4-7 data or size. Block transfers are not implemented:
//! the server aborts them with 0x05040001, as python-canopen's server does, and clients
//! then fall back to segmented transfer.

use super::NodeId;
use crate::can::CanFrame;
use std::fmt;

/// An SDO abort code with its CiA 301 meaning.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct AbortCode(pub u32);

impl AbortCode {
    pub const TOGGLE: Self = Self(0x0503_0000);
    pub const TIMEOUT: Self = Self(0x0504_0000);
    pub const BAD_COMMAND: Self = Self(0x0504_0001);
    pub const OUT_OF_MEMORY: Self = Self(0x0504_0005);
    pub const UNSUPPORTED_ACCESS: Self = Self(0x0601_0000);
    pub const WRITE_ONLY: Self = Self(0x0601_0001);
    pub const READ_ONLY: Self = Self(0x0601_0002);
    pub const NO_OBJECT: Self = Self(0x0602_0000);
    pub const NOT_MAPPABLE: Self = Self(0x0604_0041);
    pub const PDO_TOO_LONG: Self = Self(0x0604_0042);
    pub const INCOMPATIBLE: Self = Self(0x0604_0043);
    pub const HARDWARE: Self = Self(0x0606_0000);
    pub const LENGTH_MISMATCH: Self = Self(0x0607_0010);
    pub const TOO_LONG: Self = Self(0x0607_0012);
    pub const TOO_SHORT: Self = Self(0x0607_0013);
    pub const NO_SUBINDEX: Self = Self(0x0609_0011);
    pub const INVALID_VALUE: Self = Self(0x0609_0030);
    pub const VALUE_TOO_HIGH: Self = Self(0x0609_0031);
    pub const VALUE_TOO_LOW: Self = Self(0x0609_0032);
    pub const GENERAL: Self = Self(0x0800_0000);
    pub const CANNOT_STORE: Self = Self(0x0800_0020);
    pub const LOCAL_CONTROL: Self = Self(0x0800_0021);
    pub const DEVICE_STATE: Self = Self(0x0800_0022);

    pub fn description(self) -> &'static str {
        match self.0 {
            0x0503_0000 => "toggle bit not alternated",
            0x0504_0000 => "SDO protocol timed out",
            0x0504_0001 => "client/server command specifier not valid or unknown",
            0x0504_0002 => "invalid block size",
            0x0504_0003 => "invalid sequence number",
            0x0504_0004 => "CRC error",
            0x0504_0005 => "out of memory",
            0x0601_0000 => "unsupported access to an object",
            0x0601_0001 => "attempt to read a write-only object",
            0x0601_0002 => "attempt to write a read-only object",
            0x0602_0000 => "object does not exist in the object dictionary",
            0x0604_0041 => "object cannot be mapped to the PDO",
            0x0604_0042 => {
                "the number and length of the objects to be mapped would exceed the PDO length"
            }
            0x0604_0043 => "general parameter incompatibility",
            0x0604_0047 => "general internal incompatibility in the device",
            0x0606_0000 => "access failed due to a hardware error",
            0x0607_0010 => "data type does not match, length of service parameter does not match",
            0x0607_0012 => "data type does not match, length of service parameter too high",
            0x0607_0013 => "data type does not match, length of service parameter too low",
            0x0609_0011 => "subindex does not exist",
            0x0609_0030 => "invalid value for parameter",
            0x0609_0031 => "value of parameter written too high",
            0x0609_0032 => "value of parameter written too low",
            0x0609_0036 => "maximum value is less than minimum value",
            0x060A_0023 => "resource not available: SDO connection",
            0x0800_0000 => "general error",
            0x0800_0020 => "data cannot be transferred or stored to the application",
            0x0800_0021 => "data cannot be transferred or stored because of local control",
            0x0800_0022 => {
                "data cannot be transferred or stored because of the present device state"
            }
            0x0800_0023 => {
                "object dictionary dynamic generation failed or no object dictionary is present"
            }
            0x0800_0024 => "no data available",
            _ => "unknown abort code",
        }
    }
}

impl fmt::Display for AbortCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "0x{:08X} ({})", self.0, self.description())
    }
}

fn header(cmd: u8, index: u16, sub: u8) -> [u8; 8] {
    let i = index.to_le_bytes();
    [cmd, i[0], i[1], sub, 0, 0, 0, 0]
}

/// An abort frame payload.
pub fn abort_payload(index: u16, sub: u8, code: AbortCode) -> [u8; 8] {
    let mut d = header(0x80, index, sub);
    d[4..].copy_from_slice(&code.0.to_le_bytes());
    d
}

fn mux(d: &[u8; 8]) -> (u16, u8) {
    (u16::from_le_bytes([d[1], d[2]]), d[3])
}

/// Bring a received SDO frame to 8 bytes (a short frame is padded with zeros).
pub fn pad(data: &[u8]) -> [u8; 8] {
    let mut d = [0u8; 8];
    let n = data.len().min(8);
    d[..n].copy_from_slice(&data[..n]);
    d
}

// ---------------------------------------------------------------------------- client

/// Why a client transfer failed.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum SdoError {
    /// The server aborted the transfer.
    #[error("SDO abort {code} on 0x{index:04X}:{sub:02X}")]
    Aborted {
        index: u16,
        sub: u8,
        code: AbortCode,
    },
    /// The client aborted (bad answer, toggle error, timeout); the abort frame was sent.
    #[error("SDO transfer of 0x{index:04X}:{sub:02X} aborted by the client: {code}")]
    ClientAbort {
        index: u16,
        sub: u8,
        code: AbortCode,
    },
}

impl SdoError {
    pub fn code(&self) -> AbortCode {
        match self {
            SdoError::Aborted { code, .. } | SdoError::ClientAbort { code, .. } => *code,
        }
    }
}

/// What the client wants next after a response.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum ClientStep {
    /// Send this request frame (0x600 + id) and wait for the next response.
    Send(CanFrame),
    /// The upload finished with these bytes.
    Uploaded(Vec<u8>),
    /// The download finished.
    Downloaded,
    /// The transfer failed; if `send` is set, that abort frame must go on the bus.
    Failed {
        error: SdoError,
        send: Option<CanFrame>,
    },
    /// The frame did not belong to the transfer in progress (ignored).
    Ignored,
}

#[derive(Clone, Debug)]
enum Transfer {
    Upload {
        data: Vec<u8>,
        size: Option<usize>,
        toggle: bool,
        /// The server's initiate response came (segments are due only after it).
        initiated: bool,
    },
    Download {
        data: Vec<u8>,
        sent: usize,
        toggle: bool,
        segmented: bool,
        last: bool,
    },
}

/// An SDO client for one server. One transfer at a time; `now` is used only for the
/// timeout, which the owner checks with [`SdoClient::poll`].
#[derive(Clone, Debug)]
pub struct SdoClient {
    node: NodeId,
    index: u16,
    sub: u8,
    transfer: Option<Transfer>,
    deadline: f64,
    pub timeout_s: f64,
}

impl SdoClient {
    pub fn new(node: NodeId, timeout_s: f64) -> Self {
        Self {
            node,
            index: 0,
            sub: 0,
            transfer: None,
            deadline: 0.0,
            timeout_s,
        }
    }

    pub fn node(&self) -> NodeId {
        self.node
    }

    pub fn busy(&self) -> bool {
        self.transfer.is_some()
    }

    fn request(&self, d: [u8; 8]) -> CanFrame {
        CanFrame::std(self.node.sdo_rx(), &d)
    }

    /// Start reading `index:sub`; returns the initiate frame.
    pub fn upload(&mut self, index: u16, sub: u8, now: f64) -> CanFrame {
        self.index = index;
        self.sub = sub;
        self.transfer = Some(Transfer::Upload {
            data: Vec::new(),
            size: None,
            toggle: false,
            initiated: false,
        });
        self.deadline = now + self.timeout_s;
        self.request(header(0x40, index, sub))
    }

    /// Start writing `data` to `index:sub` (expedited up to 4 bytes, else segmented).
    pub fn download(&mut self, index: u16, sub: u8, data: &[u8], now: f64) -> CanFrame {
        self.index = index;
        self.sub = sub;
        self.deadline = now + self.timeout_s;
        let segmented = data.is_empty() || data.len() > 4;
        let d = if segmented {
            let mut d = header(0x21, index, sub);
            d[4..].copy_from_slice(&(data.len() as u32).to_le_bytes());
            d
        } else {
            let n = 4 - data.len() as u8;
            let mut d = header(0x23 | (n << 2), index, sub);
            d[4..4 + data.len()].copy_from_slice(data);
            d
        };
        self.transfer = Some(Transfer::Download {
            data: data.to_vec(),
            sent: 0,
            toggle: false,
            segmented,
            last: false,
        });
        self.request(d)
    }

    fn fail(&mut self, code: AbortCode) -> ClientStep {
        self.transfer = None;
        let (index, sub) = (self.index, self.sub);
        ClientStep::Failed {
            error: SdoError::ClientAbort { index, sub, code },
            send: Some(self.request(abort_payload(index, sub, code))),
        }
    }

    /// Check the timeout: on expiry the transfer fails and an abort (0x05040000) is sent.
    pub fn poll(&mut self, now: f64) -> Option<ClientStep> {
        (self.transfer.is_some() && now >= self.deadline).then(|| self.fail(AbortCode::TIMEOUT))
    }

    /// Restart the timeout of a transfer in progress at `now` (for an owner that was
    /// not scheduled for a while and so could not have seen the answer).
    pub fn extend(&mut self, now: f64) {
        if self.transfer.is_some() {
            self.deadline = self.deadline.max(now + self.timeout_s);
        }
    }

    /// Abort the transfer in progress (e.g. the caller gave up); returns the frame.
    pub fn cancel(&mut self, code: AbortCode) -> Option<CanFrame> {
        self.transfer.as_ref()?;
        match self.fail(code) {
            ClientStep::Failed { send, .. } => send,
            _ => None,
        }
    }

    /// Feed a server response (COB-ID 0x580 + id); returns what to do next.
    pub fn on_response(&mut self, data: &[u8], now: f64) -> ClientStep {
        let Some(transfer) = self.transfer.as_mut() else {
            return ClientStep::Ignored;
        };
        let d = pad(data);
        let scs = d[0] >> 5;
        if scs == 4 {
            let (index, sub) = mux(&d);
            if (index, sub) != (self.index, self.sub) && index != 0 {
                return ClientStep::Ignored;
            }
            self.transfer = None;
            let code = AbortCode(u32::from_le_bytes([d[4], d[5], d[6], d[7]]));
            return ClientStep::Failed {
                error: SdoError::Aborted {
                    index: self.index,
                    sub: self.sub,
                    code,
                },
                send: None,
            };
        }
        self.deadline = now + self.timeout_s;
        match transfer {
            Transfer::Upload {
                data: buf,
                size,
                toggle,
                initiated,
            } => match scs {
                // One initiate response, then segments only after it: a segment
                // before the initiate (a stale or stray frame) is not this transfer's.
                2 if !*initiated => {
                    if mux(&d) != (self.index, self.sub) {
                        return self.fail(AbortCode::BAD_COMMAND);
                    }
                    let expedited = d[0] & 0x02 != 0;
                    let sized = d[0] & 0x01 != 0;
                    if expedited {
                        let n = if sized {
                            4 - usize::from((d[0] >> 2) & 3)
                        } else {
                            4
                        };
                        let out = d[4..4 + n].to_vec();
                        self.transfer = None;
                        return ClientStep::Uploaded(out);
                    }
                    if sized {
                        *size = Some(u32::from_le_bytes([d[4], d[5], d[6], d[7]]) as usize);
                    }
                    *initiated = true;
                    let t = *toggle;
                    ClientStep::Send(CanFrame::std(
                        self.node.sdo_rx(),
                        &header(0x60 | (u8::from(t) << 4), 0, 0),
                    ))
                }
                0 if *initiated => {
                    let t = d[0] & 0x10 != 0;
                    if t != *toggle {
                        return self.fail(AbortCode::TOGGLE);
                    }
                    let n = usize::from((d[0] >> 1) & 7);
                    buf.extend_from_slice(&d[1..8 - n]);
                    *toggle = !*toggle;
                    if d[0] & 0x01 != 0 {
                        let out = std::mem::take(buf);
                        let expected = *size;
                        self.transfer = None;
                        if expected.is_some_and(|s| s != out.len()) {
                            let code = AbortCode::LENGTH_MISMATCH;
                            let (index, sub) = (self.index, self.sub);
                            return ClientStep::Failed {
                                error: SdoError::ClientAbort { index, sub, code },
                                send: Some(self.request(abort_payload(index, sub, code))),
                            };
                        }
                        return ClientStep::Uploaded(out);
                    }
                    let t = *toggle;
                    ClientStep::Send(CanFrame::std(
                        self.node.sdo_rx(),
                        &header(0x60 | (u8::from(t) << 4), 0, 0),
                    ))
                }
                _ => self.fail(AbortCode::BAD_COMMAND),
            },
            Transfer::Download {
                data: buf,
                sent,
                toggle,
                segmented,
                last,
            } => {
                let expect_initiate = *sent == 0 && !*last;
                match scs {
                    3 if expect_initiate => {
                        if mux(&d) != (self.index, self.sub) {
                            return self.fail(AbortCode::BAD_COMMAND);
                        }
                        if !*segmented {
                            self.transfer = None;
                            return ClientStep::Downloaded;
                        }
                    }
                    1 if !expect_initiate => {
                        let t = d[0] & 0x10 != 0;
                        if t != *toggle {
                            return self.fail(AbortCode::TOGGLE);
                        }
                        *toggle = !*toggle;
                        if *last {
                            self.transfer = None;
                            return ClientStep::Downloaded;
                        }
                    }
                    _ => return self.fail(AbortCode::BAD_COMMAND),
                }
                // Next segment.
                let chunk = (buf.len() - *sent).min(7);
                let is_last = *sent + chunk == buf.len();
                let n = (7 - chunk) as u8;
                let mut out = [0u8; 8];
                out[0] = (u8::from(*toggle) << 4) | (n << 1) | u8::from(is_last);
                out[1..1 + chunk].copy_from_slice(&buf[*sent..*sent + chunk]);
                *sent += chunk;
                *last = is_last;
                ClientStep::Send(CanFrame::std(self.node.sdo_rx(), &out))
            }
        }
    }
}

// ---------------------------------------------------------------------------- server

/// What a server needs from the object dictionary behind it.
pub trait ObjectAccess {
    /// Read an entry's bytes, or an abort code.
    fn read(&mut self, index: u16, sub: u8) -> Result<Vec<u8>, AbortCode>;
    /// Write an entry, or refuse with an abort code.
    fn write(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), AbortCode>;
}

#[derive(Clone, Debug)]
enum Serving {
    Download {
        index: u16,
        sub: u8,
        size: Option<usize>,
        data: Vec<u8>,
        toggle: bool,
    },
    Upload {
        index: u16,
        sub: u8,
        data: Vec<u8>,
        sent: usize,
        toggle: bool,
    },
}

/// An SDO server: one transfer at a time, as CiA 301 allows per SDO channel.
#[derive(Clone, Debug, Default)]
pub struct SdoServer {
    serving: Option<Serving>,
    /// Requests answered with an abort (for diagnostics).
    pub aborts_sent: u64,
}

impl SdoServer {
    pub fn new() -> Self {
        Self::default()
    }

    /// Answer a request (COB-ID 0x600 + id); the result is the response payload (to
    /// 0x580 + id), or `None` when none is due (a client's abort).
    pub fn on_request(&mut self, data: &[u8], od: &mut dyn ObjectAccess) -> Option<[u8; 8]> {
        let d = pad(data);
        let ccs = d[0] >> 5;
        let (index, sub) = mux(&d);
        let r = match ccs {
            1 => self.download_initiate(&d, od),
            0 => self.download_segment(&d, od),
            2 => self.upload_initiate(index, sub, od),
            3 => self.upload_segment(&d),
            4 => {
                self.serving = None;
                return None;
            }
            _ => Err((index, sub, AbortCode::BAD_COMMAND)),
        };
        Some(r.unwrap_or_else(|(i, s, code)| {
            self.serving = None;
            self.aborts_sent += 1;
            abort_payload(i, s, code)
        }))
    }

    fn current_mux(&self) -> (u16, u8) {
        match &self.serving {
            Some(Serving::Download { index, sub, .. } | Serving::Upload { index, sub, .. }) => {
                (*index, *sub)
            }
            None => (0, 0),
        }
    }

    fn download_initiate(
        &mut self,
        d: &[u8; 8],
        od: &mut dyn ObjectAccess,
    ) -> Result<[u8; 8], (u16, u8, AbortCode)> {
        let (index, sub) = mux(d);
        let expedited = d[0] & 0x02 != 0;
        let sized = d[0] & 0x01 != 0;
        self.serving = None;
        if expedited {
            let n = if sized {
                4 - usize::from((d[0] >> 2) & 3)
            } else {
                4
            };
            od.write(index, sub, &d[4..4 + n])
                .map_err(|c| (index, sub, c))?;
            return Ok(header(0x60, index, sub));
        }
        let size = sized.then(|| u32::from_le_bytes([d[4], d[5], d[6], d[7]]) as usize);
        if size.is_some_and(|s| s > 1 << 20) {
            return Err((index, sub, AbortCode::OUT_OF_MEMORY));
        }
        // Check the object exists and is writable before taking segments.
        od.read(index, sub)
            .or_else(|c| {
                if c == AbortCode::WRITE_ONLY {
                    Ok(Vec::new())
                } else {
                    Err(c)
                }
            })
            .map_err(|c| (index, sub, c))?;
        self.serving = Some(Serving::Download {
            index,
            sub,
            size,
            data: Vec::new(),
            toggle: false,
        });
        Ok(header(0x60, index, sub))
    }

    fn download_segment(
        &mut self,
        d: &[u8; 8],
        od: &mut dyn ObjectAccess,
    ) -> Result<[u8; 8], (u16, u8, AbortCode)> {
        let (mi, ms) = self.current_mux();
        let Some(Serving::Download {
            index,
            sub,
            size,
            data,
            toggle,
        }) = self.serving.as_mut()
        else {
            return Err((mi, ms, AbortCode::BAD_COMMAND));
        };
        let (index, sub) = (*index, *sub);
        let t = d[0] & 0x10 != 0;
        if t != *toggle {
            return Err((index, sub, AbortCode::TOGGLE));
        }
        let n = usize::from((d[0] >> 1) & 7);
        data.extend_from_slice(&d[1..8 - n]);
        if data.len() > 1 << 20 {
            return Err((index, sub, AbortCode::OUT_OF_MEMORY));
        }
        *toggle = !*toggle;
        let resp = header(0x20 | (u8::from(t) << 4), 0, 0);
        if d[0] & 0x01 != 0 {
            let data = std::mem::take(data);
            let size = *size;
            self.serving = None;
            if let Some(s) = size {
                if s != data.len() {
                    return Err((index, sub, AbortCode::LENGTH_MISMATCH));
                }
            }
            od.write(index, sub, &data).map_err(|c| (index, sub, c))?;
        }
        Ok(resp)
    }

    fn upload_initiate(
        &mut self,
        index: u16,
        sub: u8,
        od: &mut dyn ObjectAccess,
    ) -> Result<[u8; 8], (u16, u8, AbortCode)> {
        self.serving = None;
        let data = od.read(index, sub).map_err(|c| (index, sub, c))?;
        if !data.is_empty() && data.len() <= 4 {
            let n = 4 - data.len() as u8;
            let mut r = header(0x43 | (n << 2), index, sub);
            r[4..4 + data.len()].copy_from_slice(&data);
            return Ok(r);
        }
        let mut r = header(0x41, index, sub);
        r[4..].copy_from_slice(&(data.len() as u32).to_le_bytes());
        self.serving = Some(Serving::Upload {
            index,
            sub,
            data,
            sent: 0,
            toggle: false,
        });
        Ok(r)
    }

    fn upload_segment(&mut self, d: &[u8; 8]) -> Result<[u8; 8], (u16, u8, AbortCode)> {
        let (mi, ms) = self.current_mux();
        let Some(Serving::Upload {
            index,
            sub,
            data,
            sent,
            toggle,
        }) = self.serving.as_mut()
        else {
            return Err((mi, ms, AbortCode::BAD_COMMAND));
        };
        let t = d[0] & 0x10 != 0;
        if t != *toggle {
            return Err((*index, *sub, AbortCode::TOGGLE));
        }
        let chunk = (data.len() - *sent).min(7);
        let last = *sent + chunk == data.len();
        let mut r = [0u8; 8];
        r[0] = (u8::from(t) << 4) | (((7 - chunk) as u8) << 1) | u8::from(last);
        r[1..1 + chunk].copy_from_slice(&data[*sent..*sent + chunk]);
        *sent += chunk;
        *toggle = !*toggle;
        if last {
            self.serving = None;
        }
        Ok(r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;

    #[derive(Default)]
    struct Od(BTreeMap<(u16, u8), Vec<u8>>);

    impl ObjectAccess for Od {
        fn read(&mut self, index: u16, sub: u8) -> Result<Vec<u8>, AbortCode> {
            if index == 0x2FFF {
                return Err(AbortCode::WRITE_ONLY);
            }
            self.0
                .get(&(index, sub))
                .cloned()
                .ok_or(AbortCode::NO_OBJECT)
        }
        fn write(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), AbortCode> {
            if index == 0x1000 {
                return Err(AbortCode::READ_ONLY);
            }
            if index == 0x2FFF {
                return Ok(());
            }
            let e = self.0.get_mut(&(index, sub)).ok_or(AbortCode::NO_OBJECT)?;
            *e = data.to_vec();
            Ok(())
        }
    }

    #[test]
    fn upload_segment_before_the_initiate_response_is_refused() {
        let node = NodeId::new(5).unwrap();
        let mut c = SdoClient::new(node, 1.0);
        c.upload(0x6064, 0, 0.0);
        // A last segment of 6 bytes, toggle 0, where the initiate response is due.
        match c.on_response(&[0x03, 1, 2, 3, 4, 5, 6, 0], 0.1) {
            ClientStep::Failed { error, .. } => assert_eq!(error.code(), AbortCode::BAD_COMMAND),
            other => panic!("{other:?}"),
        }
        // A second initiate response in the middle of a segmented upload, likewise.
        c.upload(0x6064, 0, 0.2);
        assert!(matches!(
            c.on_response(&[0x41, 0x64, 0x60, 0, 10, 0, 0, 0], 0.3),
            ClientStep::Send(_)
        ));
        assert!(matches!(
            c.on_response(&[0x41, 0x64, 0x60, 0, 10, 0, 0, 0], 0.4),
            ClientStep::Failed { .. }
        ));
    }

    fn od() -> Od {
        let mut o = Od::default();
        o.0.insert((0x1000, 0), vec![0x92, 0x01, 0x02, 0x00]);
        o.0.insert((0x1008, 0), b"CiA 402 drive emulator".to_vec());
        o.0.insert((0x6060, 0), vec![1]);
        o.0.insert((0x2000, 0), Vec::new());
        o
    }

    /// Run a client transfer against a server to its end, returning every frame.
    fn run(
        client: &mut SdoClient,
        first: CanFrame,
        server: &mut SdoServer,
        od: &mut Od,
    ) -> (ClientStep, Vec<CanFrame>) {
        let mut wire = vec![first];
        let mut req = first;
        for _ in 0..1000 {
            let Some(resp) = server.on_request(req.data(), od) else {
                panic!("no response to {req}");
            };
            let resp = CanFrame::std(0x580 + u16::from(client.node().get()), &resp);
            wire.push(resp);
            match client.on_response(resp.data(), 0.0) {
                ClientStep::Send(f) => {
                    wire.push(f);
                    req = f;
                }
                other => return (other, wire),
            }
        }
        panic!("transfer did not end");
    }

    fn node() -> NodeId {
        NodeId::new(2).unwrap()
    }

    #[test]
    fn expedited_upload_and_download_bytes() {
        let (mut c, mut s, mut o) = (SdoClient::new(node(), 1.0), SdoServer::new(), od());
        let f = c.upload(0x1000, 0, 0.0);
        assert_eq!(f.to_string(), "602#4000100000000000");
        let (r, wire) = run(&mut c, f, &mut s, &mut o);
        assert_eq!(wire[1].to_string(), "582#4300100092010200");
        assert_eq!(r, ClientStep::Uploaded(vec![0x92, 0x01, 0x02, 0x00]));
        let f = c.download(0x6060, 0, &[6], 0.0);
        assert_eq!(f.to_string(), "602#2F60600006000000");
        let (r, wire) = run(&mut c, f, &mut s, &mut o);
        assert_eq!(wire[1].to_string(), "582#6060600000000000");
        assert_eq!(r, ClientStep::Downloaded);
        assert_eq!(o.0[&(0x6060, 0)], vec![6]);
    }

    #[test]
    fn segmented_transfers_of_every_length() {
        for len in [0usize, 5, 6, 7, 8, 13, 14, 15, 100] {
            let payload: Vec<u8> = (0..len as u8).map(|i| i.wrapping_mul(37)).collect();
            let (mut c, mut s, mut o) = (SdoClient::new(node(), 1.0), SdoServer::new(), od());
            let f = c.download(0x2000, 0, &payload, 0.0);
            let (r, _) = run(&mut c, f, &mut s, &mut o);
            assert_eq!(r, ClientStep::Downloaded, "len {len}");
            assert_eq!(o.0[&(0x2000, 0)], payload, "len {len}");
            let f = c.upload(0x2000, 0, 0.0);
            let (r, wire) = run(&mut c, f, &mut s, &mut o);
            if len > 4 || len == 0 {
                assert_eq!(wire[1].data()[0], 0x41, "segmented initiate for len {len}");
            }
            assert_eq!(r, ClientStep::Uploaded(payload), "len {len}");
        }
    }

    #[test]
    fn segmented_upload_bytes_match_cia_301() {
        let (mut c, mut s, mut o) = (SdoClient::new(node(), 1.0), SdoServer::new(), od());
        let f = c.upload(0x1008, 0, 0.0);
        let (r, wire) = run(&mut c, f, &mut s, &mut o);
        let text: Vec<String> = wire.iter().map(ToString::to_string).collect();
        let want = [
            "602#4008100000000000",
            "582#4108100016000000",
            "602#6000000000000000",
            "582#0043694120343032",
            "602#7000000000000000",
            "582#1020647269766520",
            "602#6000000000000000",
            "582#00656D756C61746F",
            "602#7000000000000000",
            "582#1D72000000000000",
        ];
        assert_eq!(text, want);
        assert_eq!(r, ClientStep::Uploaded(b"CiA 402 drive emulator".to_vec()));
    }

    #[test]
    fn server_aborts_become_typed_errors_with_the_code() {
        let (mut c, mut s, mut o) = (SdoClient::new(node(), 1.0), SdoServer::new(), od());
        let f = c.download(0x1000, 0, &[1, 2, 3, 4], 0.0);
        let (r, wire) = run(&mut c, f, &mut s, &mut o);
        assert_eq!(wire[1].to_string(), "582#8000100002000106");
        let ClientStep::Failed { error, send: None } = r else {
            panic!("{r:?}")
        };
        assert_eq!(error.code(), AbortCode::READ_ONLY);
        assert!(
            error
                .to_string()
                .contains("0x06010002 (attempt to write a read-only object)"),
            "{error}"
        );
        let f = c.upload(0x5555, 1, 0.0);
        let (r, _) = run(&mut c, f, &mut s, &mut o);
        assert!(matches!(
            r,
            ClientStep::Failed {
                error: SdoError::Aborted {
                    code: AbortCode::NO_OBJECT,
                    index: 0x5555,
                    sub: 1
                },
                ..
            }
        ));
        // Block transfers are refused with 0x05040001.
        let resp = s
            .on_request(&[0xA0, 0x00, 0x10, 0, 0, 0, 0, 0], &mut o)
            .unwrap();
        assert_eq!(resp, abort_payload(0x1000, 0, AbortCode::BAD_COMMAND));
    }

    #[test]
    fn toggle_errors_and_timeouts_abort() {
        let (mut c, mut s, mut o) = (SdoClient::new(node(), 0.5), SdoServer::new(), od());
        // Server side: a download segment with the wrong toggle.
        s.on_request(&header(0x21, 0x2000, 0), &mut o).unwrap();
        let r = s
            .on_request(&[0x10 | (6 << 1) | 1, 9, 0, 0, 0, 0, 0, 0], &mut o)
            .unwrap();
        assert_eq!(r, abort_payload(0x2000, 0, AbortCode::TOGGLE));
        // Client side: a segment with the wrong toggle.
        c.upload(0x1008, 0, 0.0);
        assert!(matches!(
            c.on_response(&[0x41, 0x08, 0x10, 0, 22, 0, 0, 0], 0.0),
            ClientStep::Send(_)
        ));
        let r = c.on_response(&[0x10, 1, 2, 3, 4, 5, 6, 7], 0.0);
        let ClientStep::Failed {
            error,
            send: Some(abort),
        } = r
        else {
            panic!("{r:?}")
        };
        assert_eq!(error.code(), AbortCode::TOGGLE);
        assert_eq!(abort.to_string(), "602#8008100000000305");
        // Timeout.
        c.upload(0x1000, 0, 10.0);
        assert!(c.poll(10.4).is_none());
        let Some(ClientStep::Failed {
            error,
            send: Some(f),
        }) = c.poll(10.6)
        else {
            panic!()
        };
        assert_eq!(error.code(), AbortCode::TIMEOUT);
        assert_eq!(f.data()[0], 0x80);
        assert!(!c.busy());
        // A response for another object is ignored only if it is an abort of another
        // transfer; a stray response with nothing in progress is ignored.
        assert_eq!(
            c.on_response(&[0x60, 0, 0, 0, 0, 0, 0, 0], 11.0),
            ClientStep::Ignored
        );
    }
}

#[cfg(test)]
mod random_input {
    use super::*;

    struct Od;
    impl ObjectAccess for Od {
        fn read(&mut self, index: u16, _sub: u8) -> Result<Vec<u8>, AbortCode> {
            match index {
                0x1000 => Ok(vec![1, 2, 3, 4]),
                0x1008 => Ok(vec![b'x'; 30]),
                _ => Err(AbortCode::NO_OBJECT),
            }
        }
        fn write(&mut self, index: u16, _sub: u8, _data: &[u8]) -> Result<(), AbortCode> {
            if index == 0x2000 {
                Ok(())
            } else {
                Err(AbortCode::READ_ONLY)
            }
        }
    }

    #[test]
    fn random_requests_and_responses_never_panic() {
        let mut x: u64 = 99;
        let mut byte = || {
            x = x
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (x >> 33) as u8
        };
        let mut server = SdoServer::new();
        let mut client = SdoClient::new(NodeId::new(1).unwrap(), 1.0);
        for i in 0..20_000 {
            let len = usize::from(byte()) % 10;
            let mut frame: Vec<u8> = (0..len).map(|_| byte()).collect();
            // Bias towards real command specifiers and objects so deep states are hit.
            if len > 3 && i % 2 == 0 {
                frame[1] = [0x00, 0x08, 0x00][i % 3];
                frame[2] = [0x10, 0x10, 0x20][i % 3];
            }
            let _ = server.on_request(&frame, &mut Od);
            if !client.busy() {
                match i % 3 {
                    0 => drop(client.upload(0x1008, 0, 0.0)),
                    1 => drop(client.download(0x2000, 0, &[1; 9], 0.0)),
                    _ => drop(client.upload(0x1000, 0, 0.0)),
                }
            }
            let _ = client.on_response(&frame, 0.0);
        }
    }
}
