//! SLCAN (Lawicel ASCII) framing, sans-IO: what a host writes to a USB-CAN adapter and
//! what the adapter writes back.
//!
//! Every command ends with CR; the adapter answers CR for OK and BEL (0x07) for an
//! error. Frames travel as `tiiildd..` (11-bit), `Tiiiiiiiildd..` (29-bit), `riiil` /
//! `Riiiiiiiil` (remote), optionally followed by a 4-hex-digit millisecond timestamp
//! (0000-EA5F) when the adapter's timestamps are on (`Z1`).
//!
//! Both directions have a decoder fed with whatever chunks the serial port gives
//! (a byte at a time or megabytes): [`CommandDecoder`] on the adapter side (the
//! emulator) and [`MessageDecoder`] on the host side (the driver). A malformed line is
//! skipped and counted, and the decoders resynchronise at the next CR or BEL, so a
//! burst of line noise costs the lines it touched and never the reader.

use crate::can::{CanFrame, CanId};
use std::fmt::Write as _;

pub const CR: u8 = b'\r';
pub const BEL: u8 = 0x07;
/// Longest valid line: `T` + 8 id + 1 dlc + 16 data + 4 timestamp.
pub const MAX_LINE: usize = 30;

/// Nominal bitrates of the `S0`..`S8` commands (Lawicel numbering).
pub const BITRATES: [u32; 9] = [
    10_000, 20_000, 50_000, 100_000, 125_000, 250_000, 500_000, 800_000, 1_000_000,
];

/// The `Sn` code of a bitrate (bits/s), if it has one.
pub fn bitrate_code(bitrate: u32) -> Option<u8> {
    BITRATES.iter().position(|&b| b == bitrate).map(|i| i as u8)
}

/// A host -> adapter command.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Command {
    /// `O`: open the channel (normal mode).
    Open,
    /// `L`: open listen-only.
    ListenOnly,
    /// `C`: close the channel.
    Close,
    /// `Sn`: bitrate code 0..=8 (see [`BITRATES`]); only while closed.
    Bitrate(u8),
    /// `sxxyy`: SJA1000 bit timing registers BTR0, BTR1.
    BitTiming(u8, u8),
    /// `t`/`T`/`r`/`R`: transmit a frame.
    Transmit(CanFrame),
    /// `F`: read the status flags.
    Status,
    /// `V`: hardware and software version.
    Version,
    /// `N`: serial number.
    Serial,
    /// `Zn`: timestamps off (0) / on (1).
    Timestamps(bool),
    /// `Mxxxxxxxx`: acceptance code.
    AcceptanceCode(u32),
    /// `mxxxxxxxx`: acceptance mask.
    AcceptanceMask(u32),
}

/// An adapter -> host message.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Message {
    /// A received frame, with the adapter's millisecond timestamp if they are on.
    Frame {
        frame: CanFrame,
        timestamp_ms: Option<u16>,
    },
    /// CR alone: the last command was accepted.
    Ok,
    /// BEL: the last command was refused.
    Error,
    /// `z` / `Z`: a transmit command was queued (Lawicel; some adapters send plain CR).
    Transmitted { extended: bool },
    /// `Fxx`: status flags (bit 0 RX FIFO full, 1 TX FIFO full, 2 error warning,
    /// 3 data overrun, 5 error passive, 6 arbitration lost, 7 bus error).
    Status(u8),
    /// `Vhhss`: hardware and software version.
    Version { hardware: u8, software: u8 },
    /// `Nxxxx`: serial number (4 characters).
    Serial(String),
}

/// Why a line was not understood.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("malformed SLCAN line {line:?}: {reason}")]
pub struct Malformed {
    /// The offending line, lossily as text (control bytes escaped).
    pub line: String,
    pub reason: &'static str,
}

fn hex_val(c: u8) -> Option<u8> {
    (c as char).to_digit(16).map(|d| d as u8)
}

fn parse_hex(s: &[u8]) -> Option<u32> {
    if s.is_empty() || s.len() > 8 {
        return None;
    }
    s.iter()
        .try_fold(0u32, |acc, &c| Some((acc << 4) | u32::from(hex_val(c)?)))
}

/// Parse the frame part of a `t/T/r/R` line (without the CR). Returns the frame and
/// the characters after it (a timestamp, if any).
fn parse_frame(line: &[u8]) -> Result<(CanFrame, &[u8]), &'static str> {
    let (ext, rtr) = match line.first() {
        Some(b't') => (false, false),
        Some(b'T') => (true, false),
        Some(b'r') => (false, true),
        Some(b'R') => (true, true),
        _ => return Err("not a frame"),
    };
    let id_len = if ext { 8 } else { 3 };
    if line.len() < 1 + id_len + 1 {
        return Err("too short for an id and a DLC");
    }
    let raw = parse_hex(&line[1..1 + id_len]).ok_or("id is not hexadecimal")?;
    let id = if ext {
        CanId::extended(raw).map_err(|_| "extended id above 0x1FFFFFFF")?
    } else {
        CanId::standard(raw as u16).map_err(|_| "standard id above 0x7FF")?
    };
    let dlc = hex_val(line[1 + id_len]).ok_or("DLC is not a digit")?;
    if dlc > 8 {
        return Err("DLC above 8 (CAN FD is not supported)");
    }
    let mut rest = &line[2 + id_len..];
    if rtr {
        return Ok((CanFrame::remote(id, dlc).expect("dlc checked"), rest));
    }
    let n = usize::from(dlc);
    if rest.len() < 2 * n {
        return Err("fewer data digits than the DLC says");
    }
    let mut data = [0u8; 8];
    for (k, d) in data.iter_mut().take(n).enumerate() {
        let hi = hex_val(rest[2 * k]).ok_or("data is not hexadecimal")?;
        let lo = hex_val(rest[2 * k + 1]).ok_or("data is not hexadecimal")?;
        *d = (hi << 4) | lo;
    }
    rest = &rest[2 * n..];
    Ok((CanFrame::new(id, &data[..n]).expect("dlc checked"), rest))
}

/// The frame as SLCAN text without the terminator (upper-case hex, as the kernel does).
pub fn frame_text(frame: &CanFrame) -> String {
    let mut s = String::with_capacity(MAX_LINE);
    let (c, id) = match (frame.id(), frame.is_remote()) {
        (CanId::Standard(i), false) => ('t', format!("{i:03X}")),
        (CanId::Extended(i), false) => ('T', format!("{i:08X}")),
        (CanId::Standard(i), true) => ('r', format!("{i:03X}")),
        (CanId::Extended(i), true) => ('R', format!("{i:08X}")),
    };
    s.push(c);
    s.push_str(&id);
    let _ = write!(s, "{:X}", frame.dlc());
    for b in frame.data() {
        let _ = write!(s, "{b:02X}");
    }
    s
}

impl Command {
    /// The command's bytes, CR included.
    pub fn encode(&self) -> Vec<u8> {
        let s = match self {
            Command::Open => "O".to_string(),
            Command::ListenOnly => "L".to_string(),
            Command::Close => "C".to_string(),
            Command::Bitrate(n) => format!("S{n}"),
            Command::BitTiming(a, b) => format!("s{a:02X}{b:02X}"),
            Command::Transmit(f) => frame_text(f),
            Command::Status => "F".to_string(),
            Command::Version => "V".to_string(),
            Command::Serial => "N".to_string(),
            Command::Timestamps(on) => format!("Z{}", u8::from(*on)),
            Command::AcceptanceCode(c) => format!("M{c:08X}"),
            Command::AcceptanceMask(m) => format!("m{m:08X}"),
        };
        let mut v = s.into_bytes();
        v.push(CR);
        v
    }

    /// Parse one command line (without its CR).
    pub fn parse(line: &[u8]) -> Result<Command, Malformed> {
        let bad = |reason| Malformed {
            line: escape(line),
            reason,
        };
        let Some(&c) = line.first() else {
            return Err(bad("empty command"));
        };
        let arg = &line[1..];
        let hex_arg = |len: usize| -> Result<u32, Malformed> {
            if arg.len() != len {
                return Err(bad("wrong argument length"));
            }
            parse_hex(arg).ok_or_else(|| bad("argument is not hexadecimal"))
        };
        match c {
            b't' | b'T' | b'r' | b'R' => {
                let (f, rest) = parse_frame(line).map_err(bad)?;
                if !rest.is_empty() {
                    return Err(bad("characters after the frame"));
                }
                Ok(Command::Transmit(f))
            }
            b'O' | b'L' | b'C' | b'F' | b'V' | b'N' if !arg.is_empty() => {
                Err(bad("this command takes no argument"))
            }
            b'O' => Ok(Command::Open),
            b'L' => Ok(Command::ListenOnly),
            b'C' => Ok(Command::Close),
            b'F' => Ok(Command::Status),
            b'V' => Ok(Command::Version),
            b'N' => Ok(Command::Serial),
            b'S' => match arg {
                [d] if (b'0'..=b'8').contains(d) => Ok(Command::Bitrate(d - b'0')),
                _ => Err(bad("bitrate code must be 0..8")),
            },
            b's' => {
                let v = hex_arg(4)?;
                Ok(Command::BitTiming((v >> 8) as u8, v as u8))
            }
            b'Z' => match arg {
                [b'0'] => Ok(Command::Timestamps(false)),
                [b'1'] => Ok(Command::Timestamps(true)),
                _ => Err(bad("timestamps take 0 or 1")),
            },
            b'M' => Ok(Command::AcceptanceCode(hex_arg(8)?)),
            b'm' => Ok(Command::AcceptanceMask(hex_arg(8)?)),
            _ => Err(bad("unknown command")),
        }
    }
}

impl Message {
    /// The message's bytes, terminator included.
    pub fn encode(&self) -> Vec<u8> {
        let s = match self {
            Message::Frame {
                frame,
                timestamp_ms,
            } => {
                let mut s = frame_text(frame);
                if let Some(t) = timestamp_ms {
                    let _ = write!(s, "{t:04X}");
                }
                s
            }
            Message::Ok => String::new(),
            Message::Error => return vec![BEL],
            Message::Transmitted { extended } => (if *extended { "Z" } else { "z" }).to_string(),
            Message::Status(f) => format!("F{f:02X}"),
            Message::Version { hardware, software } => format!("V{hardware:02X}{software:02X}"),
            Message::Serial(s) => format!("N{s}"),
        };
        let mut v = s.into_bytes();
        v.push(CR);
        v
    }

    /// Parse one line (without its CR). An empty line is [`Message::Ok`].
    pub fn parse(line: &[u8]) -> Result<Message, Malformed> {
        let bad = |reason| Malformed {
            line: escape(line),
            reason,
        };
        let Some(&c) = line.first() else {
            return Ok(Message::Ok);
        };
        let arg = &line[1..];
        match c {
            b't' | b'T' | b'r' | b'R' => {
                let (frame, rest) = parse_frame(line).map_err(bad)?;
                let timestamp_ms = match rest.len() {
                    0 => None,
                    4 => {
                        let t =
                            parse_hex(rest).ok_or_else(|| bad("timestamp is not hexadecimal"))?;
                        if t > 0xEA5F {
                            return Err(bad("timestamp above 59999 ms"));
                        }
                        Some(t as u16)
                    }
                    _ => return Err(bad("characters after the frame are not a timestamp")),
                };
                Ok(Message::Frame {
                    frame,
                    timestamp_ms,
                })
            }
            b'z' | b'Z' if arg.is_empty() => Ok(Message::Transmitted {
                extended: c == b'Z',
            }),
            b'F' if arg.len() == 2 => parse_hex(arg)
                .map(|v| Message::Status(v as u8))
                .ok_or_else(|| bad("status flags are not hexadecimal")),
            b'V' if arg.len() == 4 => parse_hex(arg)
                .map(|v| Message::Version {
                    hardware: (v >> 8) as u8,
                    software: v as u8,
                })
                .ok_or_else(|| bad("version is not hexadecimal")),
            b'N' if arg.len() == 4 && arg.iter().all(u8::is_ascii_alphanumeric) => {
                Ok(Message::Serial(String::from_utf8_lossy(arg).into_owned()))
            }
            _ => Err(bad("not an SLCAN message")),
        }
    }
}

fn escape(line: &[u8]) -> String {
    line.iter()
        .flat_map(|b| std::ascii::escape_default(*b))
        .map(char::from)
        .collect()
}

/// Line assembly shared by both decoders: bytes up to CR (a line) or BEL (an error
/// answer); LF is ignored (some adapters and terminals add it); over-long lines are
/// dropped whole.
#[derive(Debug, Default, Clone)]
struct Lines {
    buf: Vec<u8>,
    overflow: bool,
}

enum Piece {
    Line(Vec<u8>),
    /// A BEL; `discarded` if it cut off a partial line (which is then lost).
    Bel {
        discarded: bool,
    },
    TooLong,
}

const TOO_LONG: &str = "no CR within 30 characters";

impl Lines {
    fn push(&mut self, b: u8) -> Option<Piece> {
        match b {
            CR => {
                let overflow = std::mem::take(&mut self.overflow);
                let line = std::mem::take(&mut self.buf);
                Some(if overflow {
                    Piece::TooLong
                } else {
                    Piece::Line(line)
                })
            }
            BEL => {
                let discarded = !self.buf.is_empty() || self.overflow;
                self.buf.clear();
                self.overflow = false;
                Some(Piece::Bel { discarded })
            }
            b'\n' => None,
            _ => {
                if self.buf.len() >= MAX_LINE {
                    self.overflow = true;
                } else {
                    self.buf.push(b);
                }
                None
            }
        }
    }
}

/// Host side: decodes what an adapter sends. Malformed lines are skipped and counted.
#[derive(Debug, Default, Clone)]
pub struct MessageDecoder {
    lines: Lines,
    malformed: u64,
    last_error: Option<Malformed>,
}

impl MessageDecoder {
    pub fn new() -> Self {
        Self::default()
    }

    /// Feed bytes; decoded messages are appended to `out`.
    pub fn feed(&mut self, bytes: &[u8], out: &mut Vec<Message>) {
        for &b in bytes {
            let r = match self.lines.push(b) {
                None => continue,
                Some(Piece::Line(l)) => Message::parse(&l),
                Some(Piece::Bel { discarded }) => {
                    if discarded {
                        self.skip(Malformed {
                            line: "(partial line)".into(),
                            reason: "cut off by BEL",
                        });
                    }
                    Ok(Message::Error)
                }
                Some(Piece::TooLong) => Err(Malformed {
                    line: "(over-long line)".into(),
                    reason: TOO_LONG,
                }),
            };
            match r {
                Ok(m) => out.push(m),
                Err(e) => self.skip(e),
            }
        }
    }

    fn skip(&mut self, e: Malformed) {
        self.malformed += 1;
        self.last_error = Some(e);
    }

    /// Lines skipped because they were not valid SLCAN.
    pub fn malformed(&self) -> u64 {
        self.malformed
    }

    pub fn last_error(&self) -> Option<&Malformed> {
        self.last_error.as_ref()
    }
}

/// Adapter side: decodes what a host sends. Each line gives a command or the reason it
/// is refused (the adapter answers BEL).
#[derive(Debug, Default, Clone)]
pub struct CommandDecoder {
    lines: Lines,
    malformed: u64,
}

impl CommandDecoder {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn feed(&mut self, bytes: &[u8], out: &mut Vec<Result<Command, Malformed>>) {
        for &b in bytes {
            let r = match self.lines.push(b) {
                None => continue,
                Some(Piece::Line(l)) => Command::parse(&l),
                Some(Piece::Bel { .. }) => Err(Malformed {
                    line: "\\x07".into(),
                    reason: "BEL is not a command",
                }),
                Some(Piece::TooLong) => Err(Malformed {
                    line: "(over-long line)".into(),
                    reason: TOO_LONG,
                }),
            };
            if r.is_err() {
                self.malformed += 1;
            }
            out.push(r);
        }
    }

    pub fn malformed(&self) -> u64 {
        self.malformed
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frames() -> Vec<CanFrame> {
        vec![
            CanFrame::std(0x601, &[0x40, 0x41, 0x60, 0, 0, 0, 0, 0]),
            CanFrame::std(0x000, &[0x01, 0x00]),
            CanFrame::std(0x7FF, &[]),
            CanFrame::new(CanId::Extended(0x1ABC_DEF0), &[1, 2, 3]).unwrap(),
            CanFrame::remote(CanId::Standard(0x181), 8).unwrap(),
            CanFrame::remote(CanId::Extended(0x42), 0).unwrap(),
        ]
    }

    #[test]
    fn frame_text_matches_the_lawicel_examples() {
        assert_eq!(
            frame_text(&CanFrame::std(0x100, &[0x11, 0x33])),
            "t10021133"
        );
        let m = Message::parse(b"t100211334D67").unwrap();
        assert_eq!(
            m,
            Message::Frame {
                frame: CanFrame::std(0x100, &[0x11, 0x33]),
                timestamp_ms: Some(0x4D67)
            }
        );
        assert_eq!(
            Command::Transmit(frames()[3]).encode(),
            b"T1ABCDEF03010203\r"
        );
        assert_eq!(Command::Transmit(frames()[4]).encode(), b"r1818\r");
        assert_eq!(Command::Bitrate(8).encode(), b"S8\r");
        assert_eq!(bitrate_code(1_000_000), Some(8));
        assert_eq!(bitrate_code(83_333), None);
    }

    #[test]
    fn every_command_round_trips() {
        let mut cmds = vec![
            Command::Open,
            Command::ListenOnly,
            Command::Close,
            Command::Bitrate(6),
            Command::BitTiming(0x03, 0x1C),
            Command::Status,
            Command::Version,
            Command::Serial,
            Command::Timestamps(true),
            Command::Timestamps(false),
            Command::AcceptanceCode(0x1234_5678),
            Command::AcceptanceMask(0xFFFF_FFFF),
        ];
        cmds.extend(frames().into_iter().map(Command::Transmit));
        for c in cmds {
            let bytes = c.encode();
            assert_eq!(Command::parse(&bytes[..bytes.len() - 1]), Ok(c));
        }
    }

    fn messages() -> Vec<Message> {
        let mut m: Vec<Message> = frames()
            .into_iter()
            .enumerate()
            .map(|(i, frame)| Message::Frame {
                frame,
                timestamp_ms: (i % 2 == 0).then_some(i as u16 * 1000),
            })
            .collect();
        m.extend([
            Message::Ok,
            Message::Error,
            Message::Transmitted { extended: false },
            Message::Transmitted { extended: true },
            Message::Status(0xA5),
            Message::Version {
                hardware: 0x10,
                software: 0x11,
            },
            Message::Serial("A0B1".into()),
        ]);
        m
    }

    #[test]
    fn message_stream_decodes_byte_by_byte_and_at_every_split() {
        let msgs = messages();
        let stream: Vec<u8> = msgs.iter().flat_map(Message::encode).collect();
        // Byte by byte.
        let mut d = MessageDecoder::new();
        let mut out = Vec::new();
        for b in &stream {
            d.feed(std::slice::from_ref(b), &mut out);
        }
        assert_eq!(out, msgs);
        // Every split point into two chunks.
        for k in 0..=stream.len() {
            let mut d = MessageDecoder::new();
            let mut out = Vec::new();
            d.feed(&stream[..k], &mut out);
            d.feed(&stream[k..], &mut out);
            assert_eq!(out, msgs, "split at {k}");
            assert_eq!(d.malformed(), 0);
        }
    }

    #[test]
    fn command_stream_decodes_at_every_split() {
        let cmds: Vec<Command> = frames()
            .into_iter()
            .map(Command::Transmit)
            .chain([Command::Open, Command::Bitrate(8)])
            .collect();
        let stream: Vec<u8> = cmds.iter().flat_map(Command::encode).collect();
        for k in 0..=stream.len() {
            let mut d = CommandDecoder::new();
            let mut out = Vec::new();
            d.feed(&stream[..k], &mut out);
            d.feed(&stream[k..], &mut out);
            let got: Vec<Command> = out.into_iter().map(Result::unwrap).collect();
            assert_eq!(got, cmds, "split at {k}");
        }
    }

    #[test]
    fn malformed_lines_are_counted_and_the_decoder_resynchronises() {
        let good = Message::Frame {
            frame: CanFrame::std(0x701, &[0x05]),
            timestamp_ms: None,
        };
        let garbage: &[&[u8]] = &[
            b"t7012\r",                                        // DLC 2, no data
            b"t80010\r",                                       // id above 0x7FF
            b"t1019AABBCCDDEEFF001122\r",                      // DLC 9
            b"tXYZ0\r",                                        // id not hex
            b"q\r",                                            // unknown
            b"t70110512\r",                                    // 2 characters after the frame
            b"t701105EA60\r",                                  // timestamp 60000
            &[0xFF, 0x00, 0x80, b'\r'],                        // binary noise
            b"t7011050000000000000000000000000000000000000\r", // over-long
        ];
        let mut stream = Vec::new();
        for g in garbage {
            stream.extend_from_slice(g);
            stream.extend(good.encode());
        }
        let mut d = MessageDecoder::new();
        let mut out = Vec::new();
        for b in &stream {
            d.feed(std::slice::from_ref(b), &mut out);
        }
        assert_eq!(out, vec![good.clone(); garbage.len()]);
        assert_eq!(d.malformed(), garbage.len() as u64);
        assert!(
            d.last_error().unwrap().reason.contains("30"),
            "{:?}",
            d.last_error()
        );
    }

    #[test]
    fn adapter_side_refuses_bad_commands_with_a_reason() {
        let mut d = CommandDecoder::new();
        let mut out = Vec::new();
        d.feed(b"S9\rO1\rs031\rZ2\rt12\rO\r", &mut out);
        assert_eq!(out.len(), 6);
        assert!(out[..5].iter().all(Result::is_err));
        assert_eq!(out[5], Ok(Command::Open));
        assert_eq!(d.malformed(), 5);
        assert!(out[0]
            .as_ref()
            .unwrap_err()
            .to_string()
            .contains("bitrate code"));
    }
}

#[cfg(test)]
mod random_input {
    use super::*;

    /// A small deterministic generator (no dependency for a test).
    struct Lcg(u64);
    impl Lcg {
        fn next(&mut self) -> u8 {
            self.0 = self
                .0
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (self.0 >> 33) as u8
        }
    }

    #[test]
    fn random_bytes_never_panic_and_a_good_line_after_them_is_read() {
        let alphabet = b"tTrRzZFVN0123456789ABCDEFabcdef\r\x07\n\xFF";
        let good = Message::Frame {
            frame: CanFrame::std(0x181, &[1, 2, 3]),
            timestamp_ms: None,
        };
        let mut rng = Lcg(7);
        for round in 0..2000 {
            let len = usize::from(rng.next()) % 80;
            let noise: Vec<u8> = (0..len)
                .map(|_| alphabet[usize::from(rng.next()) % alphabet.len()])
                .collect();
            let mut d = MessageDecoder::new();
            let mut out = Vec::new();
            d.feed(&noise, &mut out);
            // A CR ends whatever the noise left open; then a good frame is read.
            d.feed(b"\r", &mut out);
            out.clear();
            d.feed(&good.encode(), &mut out);
            assert_eq!(out, vec![good.clone()], "round {round}: noise {noise:?}");
            let mut c = CommandDecoder::new();
            let mut cmds = Vec::new();
            c.feed(&noise, &mut cmds);
            c.feed(b"\rO\r", &mut cmds);
            assert_eq!(cmds.last(), Some(&Ok(Command::Open)), "round {round}");
        }
    }
}
