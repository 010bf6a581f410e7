//! Everything GRBL sends back, one `\r\n`-terminated line at a time, and a decoder that
//! turns an arbitrary byte stream (split anywhere, with garbage in it) into those lines.

use super::status::StatusReport;

/// One message from GRBL.
#[derive(Clone, Debug, PartialEq)]
pub enum Response {
    /// `ok`: the oldest unacknowledged line was executed or planned.
    Ok,
    /// `error:N`: the oldest unacknowledged line was refused.
    Error(u8),
    /// `ALARM:N`: the machine is in alarm; motion stopped.
    Alarm(u8),
    /// `<...>`: a real-time status report.
    Status(StatusReport),
    /// The welcome banner, e.g. `Grbl 1.1h ['$' for help]`: GRBL (re)started and its
    /// RX buffer is empty.
    Banner { firmware: String, version: String },
    /// `[MSG:...]` feedback message.
    Message(String),
    /// `[GC:...]` parser state (reply to `$G`), the words inside.
    ParserState(String),
    /// `[HLP:...]` (reply to `$`).
    Help(String),
    /// `[VER:1.1h.20190830:info]` (reply to `$I`).
    Version { version: String, info: String },
    /// `[OPT:flags,blocks,rx]` (reply to `$I`): build options, planner blocks (minus
    /// one, as GRBL counts them) and RX buffer size.
    Options {
        flags: String,
        planner_blocks: u16,
        rx_buffer: u16,
    },
    /// `[G54:x,y,z]`, `[G92:..]`, `[TLO:z]`, `[PRB:x,y,z:1]` (reply to `$#`).
    Parameter { name: String, value: String },
    /// `[echo:...]` (only with the echo build option).
    Echo(String),
    /// `$n=value` (a line of the `$$` listing).
    Setting { number: u16, value: String },
    /// `$Nn=line` (a line of the `$N` listing).
    StartupLine { index: u8, line: String },
    /// `>line:ok` or `>line:error:N`: a startup line was run (not counted by streaming).
    StartupResult {
        line: String,
        status: Result<(), u8>,
    },
    /// Anything else (a foreign device, line noise), for the error message: shown as
    /// [`crate::text::escape_bytes`] shows device bytes (printable ASCII as is, other
    /// bytes as `\xNN`, cut at 80 characters with the line's byte count).
    Other(String),
}

impl Response {
    /// Classify one line (line ending already removed), by prefix as senders do.
    pub fn parse(line: &str) -> Response {
        let line = line.trim_end_matches(['\r', '\n']);
        if line == "ok" {
            return Response::Ok;
        }
        if let Some(n) = line.strip_prefix("error:") {
            if let Ok(n) = n.trim().parse::<u8>() {
                return Response::Error(n);
            }
        }
        if let Some(n) = line.strip_prefix("ALARM:") {
            if let Ok(n) = n.trim().parse::<u8>() {
                return Response::Alarm(n);
            }
        }
        if line.starts_with('<') {
            if let Ok(r) = StatusReport::parse(line) {
                return Response::Status(r);
            }
        }
        if let Some(inner) = line.strip_prefix('[').and_then(|s| s.strip_suffix(']')) {
            if let Some(r) = parse_bracket(inner) {
                return r;
            }
        }
        if let Some(rest) = line.strip_prefix('$') {
            if let Some(r) = parse_dollar(rest) {
                return r;
            }
        }
        if let Some(rest) = line.strip_prefix('>') {
            if let Some((l, status)) = rest.rsplit_once(":ok") {
                if status.is_empty() {
                    return Response::StartupResult {
                        line: l.to_string(),
                        status: Ok(()),
                    };
                }
            }
            if let Some((l, code)) = rest.rsplit_once(":error:") {
                if let Ok(code) = code.parse() {
                    return Response::StartupResult {
                        line: l.to_string(),
                        status: Err(code),
                    };
                }
            }
        }
        if let Some(b) = parse_banner(line) {
            return b;
        }
        Response::Other(line.to_string())
    }

    /// True for the two responses that retire one streamed line.
    pub fn is_line_response(&self) -> bool {
        matches!(self, Response::Ok | Response::Error(_))
    }
}

fn parse_bracket(inner: &str) -> Option<Response> {
    let (tag, value) = inner.split_once(':')?;
    Some(match tag {
        "MSG" => Response::Message(value.to_string()),
        "GC" => Response::ParserState(value.to_string()),
        "HLP" => Response::Help(value.to_string()),
        "echo" => Response::Echo(value.trim_start().to_string()),
        "VER" => {
            let (version, info) = value.split_once(':').unwrap_or((value, ""));
            Response::Version {
                version: version.to_string(),
                info: info.to_string(),
            }
        }
        "OPT" => {
            let mut parts = value.split(',');
            let flags = parts.next()?.to_string();
            let planner_blocks = parts.next()?.trim().parse().ok()?;
            let rx_buffer = parts.next()?.trim().parse().ok()?;
            Response::Options {
                flags,
                planner_blocks,
                rx_buffer,
            }
        }
        "G54" | "G55" | "G56" | "G57" | "G58" | "G59" | "G28" | "G30" | "G92" | "TLO" | "PRB" => {
            Response::Parameter {
                name: tag.to_string(),
                value: value.to_string(),
            }
        }
        _ => return None,
    })
}

fn parse_dollar(rest: &str) -> Option<Response> {
    let (key, value) = rest.split_once('=')?;
    if let Some(idx) = key.strip_prefix('N') {
        return Some(Response::StartupLine {
            index: idx.parse().ok()?,
            line: value.to_string(),
        });
    }
    let number = key.parse().ok()?;
    // `$$` in GRBL 1.1 prints bare values; older builds append a `(comment)`.
    let value = value.split(" (").next().unwrap_or(value).trim();
    Some(Response::Setting {
        number,
        value: value.to_string(),
    })
}

/// Banners of the GRBL family: `Grbl 1.1h ['$' for help]`, `GrblHAL 1.1f [...]`, and the
/// forks senders recognise. The version must start with a digit.
fn parse_banner(line: &str) -> Option<Response> {
    let (firmware, rest) = line.split_once(' ')?;
    if !matches!(
        firmware,
        "Grbl" | "GrblHAL" | "grblHAL" | "CarbideMotion" | "gCarvin"
    ) {
        return None;
    }
    let version = rest.split_whitespace().next()?;
    if !version.starts_with(|c: char| c.is_ascii_digit()) {
        return None;
    }
    Some(Response::Banner {
        firmware: firmware.to_string(),
        version: version.to_string(),
    })
}

/// Longest line the decoder keeps; anything longer is garbage (GRBL's longest lines,
/// status reports with every field, stay well under this).
pub const MAX_LINE: usize = 256;

/// Splits a byte stream into lines, whatever the chunking. Lines end at `\n`; a `\r`
/// before it is dropped, as are empty lines (the banner starts with `\r\n`). An
/// over-long line is reported once as `Other` and the decoder resynchronises at the
/// next newline. Bytes that are not UTF-8 are replaced, so garbage never stops decoding.
#[derive(Debug, Default)]
pub struct LineDecoder {
    buf: Vec<u8>,
    overflowed: bool,
}

/// `bytes` without the carriage returns and NULs around them (as lines are trimmed).
fn trim_bytes(bytes: &[u8]) -> &[u8] {
    let keep = |b: &u8| *b != b'\r' && *b != 0;
    let start = bytes.iter().position(keep).unwrap_or(bytes.len());
    let end = bytes.iter().rposition(keep).map_or(start, |e| e + 1);
    &bytes[start..end]
}

impl LineDecoder {
    pub fn new() -> Self {
        Self::default()
    }

    /// Feed bytes; complete lines are appended to `out`.
    pub fn feed(&mut self, bytes: &[u8], out: &mut Vec<Response>) {
        for &b in bytes {
            if b == b'\n' {
                if self.overflowed {
                    self.overflowed = false;
                } else {
                    let text = String::from_utf8_lossy(&self.buf);
                    let text = text.trim_matches(['\r', '\0']);
                    if !text.is_empty() {
                        out.push(match Response::parse(text) {
                            // The bytes as received, not their lossy UTF-8 reading.
                            Response::Other(_) => {
                                Response::Other(crate::text::escape_bytes(trim_bytes(&self.buf)))
                            }
                            r => r,
                        });
                    }
                }
                self.buf.clear();
            } else if self.overflowed {
                // Discard until the next newline.
            } else if self.buf.len() >= MAX_LINE {
                // 20 bytes are at most 80 escaped characters: never cut again.
                let head = crate::text::escape_bytes_max(&self.buf[..20], 80);
                out.push(Response::Other(format!(
                    "{head}... (line longer than {MAX_LINE} bytes)"
                )));
                self.buf.clear();
                self.overflowed = true;
            } else {
                self.buf.push(b);
            }
        }
    }

    /// Bytes of the incomplete last line (for error messages).
    pub fn pending(&self) -> &[u8] {
        &self.buf
    }

    /// Forget a partial line (after a reconnect).
    pub fn clear(&mut self) {
        self.buf.clear();
        self.overflowed = false;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grbl::status::MachineState;

    const SESSION: &[u8] = b"\r\nGrbl 1.1h ['$' for help]\r\n[MSG:'$H'|'$X' to unlock]\r\n<Alarm|MPos:0.000,0.000,0.000|Bf:15,128|FS:0,0|WCO:0.000,0.000,0.000>\r\n[VER:1.1h.20190830:]\r\n[OPT:VNZ,15,128]\r\nok\r\n$0=10\r\n$100=2000.000\r\n$N0=G21\r\n>G21:ok\r\n[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]\r\n[G54:0.000,0.000,0.000]\r\n[PRB:0.000,0.000,0.000:0]\r\nerror:20\r\nALARM:2\r\n[echo: G1X1]\r\n";

    fn expected() -> Vec<Response> {
        let mut status = StatusReport::new(MachineState::Alarm, vec![0.0; 3]);
        status.buffer = Some((15, 128));
        status.feed = Some(0.0);
        status.spindle = Some(0.0);
        status.wco = Some(vec![0.0; 3]);
        vec![
            Response::Banner {
                firmware: "Grbl".into(),
                version: "1.1h".into(),
            },
            Response::Message("'$H'|'$X' to unlock".into()),
            Response::Status(status),
            Response::Version {
                version: "1.1h.20190830".into(),
                info: "".into(),
            },
            Response::Options {
                flags: "VNZ".into(),
                planner_blocks: 15,
                rx_buffer: 128,
            },
            Response::Ok,
            Response::Setting {
                number: 0,
                value: "10".into(),
            },
            Response::Setting {
                number: 100,
                value: "2000.000".into(),
            },
            Response::StartupLine {
                index: 0,
                line: "G21".into(),
            },
            Response::StartupResult {
                line: "G21".into(),
                status: Ok(()),
            },
            Response::ParserState("G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0".into()),
            Response::Parameter {
                name: "G54".into(),
                value: "0.000,0.000,0.000".into(),
            },
            Response::Parameter {
                name: "PRB".into(),
                value: "0.000,0.000,0.000:0".into(),
            },
            Response::Error(20),
            Response::Alarm(2),
            Response::Echo("G1X1".into()),
        ]
    }

    #[test]
    fn whole_session_in_one_chunk() {
        let mut d = LineDecoder::new();
        let mut out = Vec::new();
        d.feed(SESSION, &mut out);
        assert_eq!(out, expected());
    }

    #[test]
    fn byte_by_byte() {
        let mut d = LineDecoder::new();
        let mut out = Vec::new();
        for b in SESSION {
            d.feed(std::slice::from_ref(b), &mut out);
        }
        assert_eq!(out, expected());
    }

    #[test]
    fn every_split_point() {
        for cut in 0..=SESSION.len() {
            let mut d = LineDecoder::new();
            let mut out = Vec::new();
            d.feed(&SESSION[..cut], &mut out);
            d.feed(&SESSION[cut..], &mut out);
            assert_eq!(out, expected(), "split at {cut}");
        }
    }

    #[test]
    fn recovers_after_garbage() {
        let mut d = LineDecoder::new();
        let mut out = Vec::new();
        let mut junk = vec![0xFFu8, 0x00, b'<', b'|', 0xC3];
        junk.extend(std::iter::repeat_n(b'x', 1000));
        junk.extend_from_slice(b"\r\nok\r\n<Idle|MPos:oops>\r\nerror:x\r\nok\r\n");
        d.feed(&junk, &mut out);
        assert!(
            matches!(&out[0], Response::Other(s) if s.contains("longer than")),
            "{out:?}"
        );
        assert_eq!(out[1], Response::Ok);
        assert!(matches!(&out[2], Response::Other(s) if s == "<Idle|MPos:oops>"));
        assert!(matches!(&out[3], Response::Other(s) if s == "error:x"));
        assert_eq!(out[4], Response::Ok);
        assert_eq!(out.len(), 5);
        // Foreign bytes are shown escaped, as received.
        let mut out = Vec::new();
        d.feed(b"\x00\xFFab\xC3\x28\r\n", &mut out);
        assert_eq!(out, [Response::Other("\\xFFab\\xC3(".into())]);
        let mut out = Vec::new();
        d.feed(&[0xAA; 300], &mut out);
        d.feed(b"\n", &mut out);
        assert!(
            matches!(&out[0], Response::Other(s) if s.starts_with("\\xAA\\xAA") && s.ends_with("... (line longer than 256 bytes)")),
            "{out:?}"
        );
    }

    /// Random bytes (biased towards GRBL's own characters) never panic the decoder or
    /// the parsers, and a clean line after a newline always decodes.
    #[test]
    fn random_input_never_panics_and_decoding_resynchronises() {
        let alphabet =
            b"<>|:,.-0123456789okerrorALARM[]MSG$=GrblIdleRunMPosWPosBfFSOvWCO\r\n \xff\x00";
        let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        for _ in 0..2000 {
            let n = (next() % 300) as usize;
            let bytes: Vec<u8> = (0..n)
                .map(|_| alphabet[(next() % alphabet.len() as u64) as usize])
                .collect();
            let mut d = LineDecoder::new();
            let mut out = Vec::new();
            for chunk in bytes.chunks(1 + (next() % 7) as usize) {
                d.feed(chunk, &mut out);
            }
            let text = String::from_utf8_lossy(&bytes);
            let _ = StatusReport::parse(&text);
            let _ = crate::grbl::gcode::Interpreter::new()
                .execute(&crate::grbl::gcode::filter_bytes(&bytes).0, false);
            out.clear();
            d.feed(b"\nok\r\n", &mut out);
            assert_eq!(out.last(), Some(&Response::Ok), "{bytes:?}");
        }
    }

    #[test]
    fn banners_of_forks_and_non_banners() {
        assert!(matches!(
            Response::parse("GrblHAL 1.1f ['$' or '$HELP' for help]"),
            Response::Banner { firmware, version } if firmware == "GrblHAL" && version == "1.1f"
        ));
        assert!(matches!(
            Response::parse("Grbl is great"),
            Response::Other(_)
        ));
        assert!(matches!(Response::parse("Marlin 2.0"), Response::Other(_)));
        assert!(matches!(
            Response::parse(">G1X1:error:22"),
            Response::StartupResult {
                status: Err(22),
                ..
            }
        ));
        assert!(
            matches!(Response::parse("$130=200.000 (x max travel, mm)"), Response::Setting { number: 130, ref value } if value == "200.000")
        );
    }
}
