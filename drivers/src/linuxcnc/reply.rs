//! The replies of `linuxcncrsh`, sans-IO: lines split out of any chunking, and one line
//! read as what it answers.
//!
//! The shell ends `SET ... ACK`/`NAK` lines with `\n\r` and `get` replies with `\r\n`,
//! so a line ends at any run of CR and LF and empty lines do not exist. A line longer
//! than [`MAX_LINE`] is cut there (the shell's own output buffer is 4096 bytes) and
//! marked, never grown without bound.

/// The longest line kept, bytes.
pub const MAX_LINE: usize = 4096;

/// Lines out of a byte stream, whatever its chunking.
#[derive(Debug, Default)]
pub struct LineSplitter {
    partial: Vec<u8>,
    /// The line being read went past [`MAX_LINE`]: the rest up to its end is dropped.
    overflowed: bool,
}

/// One line of the shell: its text (lossy UTF-8) and whether it was cut.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Line {
    pub text: String,
    pub cut: bool,
}

impl LineSplitter {
    pub fn new() -> Self {
        Self::default()
    }

    /// Feed bytes; every line they complete is pushed to `out`.
    pub fn feed(&mut self, bytes: &[u8], out: &mut Vec<Line>) {
        for &b in bytes {
            if b == b'\r' || b == b'\n' {
                if !self.partial.is_empty() || self.overflowed {
                    out.push(Line {
                        text: String::from_utf8_lossy(&self.partial).into_owned(),
                        cut: self.overflowed,
                    });
                    self.partial.clear();
                    self.overflowed = false;
                }
            } else if self.partial.len() < MAX_LINE {
                self.partial.push(b);
            } else {
                self.overflowed = true;
            }
        }
    }
}

/// What one line says.
#[derive(Clone, Debug, PartialEq)]
pub enum Reply {
    /// `HELLO ACK <server name> <version>`.
    HelloAck { server: String },
    /// `HELLO NAK`: wrong connect password or a malformed hello.
    HelloNak,
    /// `SET <COMMAND> ACK` (verbose on).
    SetAck { command: String },
    /// `SET <COMMAND> NAK` or `SET NAK`: refused (not enabled, machine not on, a bad
    /// argument, or a command that failed while waited for).
    SetNak { command: String },
    /// `<KEY> NAK`: a `get` refused.
    GetNak { key: String },
    /// `<KEY> <value>...`: a `get` answered.
    Value { key: String, words: Vec<String> },
}

impl Reply {
    /// Read one line (already split). Keys are upper-cased as the shell writes them.
    pub fn parse(line: &str) -> Reply {
        let words: Vec<&str> = line.split_ascii_whitespace().collect();
        let upper = |s: &str| s.to_ascii_uppercase();
        match words.as_slice() {
            [h, a, rest @ ..] if upper(h) == "HELLO" && upper(a) == "ACK" => Reply::HelloAck {
                server: rest.join(" "),
            },
            [h, n] if upper(h) == "HELLO" && upper(n) == "NAK" => Reply::HelloNak,
            [s, n] if upper(s) == "SET" && upper(n) == "NAK" => Reply::SetNak {
                command: String::new(),
            },
            [s, c, a] if upper(s) == "SET" && upper(a) == "ACK" => {
                Reply::SetAck { command: upper(c) }
            }
            [s, c, n] if upper(s) == "SET" && upper(n) == "NAK" => {
                Reply::SetNak { command: upper(c) }
            }
            [g, k, n] if upper(g) == "GET" && upper(n) == "NAK" => Reply::GetNak { key: upper(k) },
            [k, n] if upper(n) == "NAK" => Reply::GetNak { key: upper(k) },
            [k, rest @ ..] => Reply::Value {
                key: upper(k),
                words: rest.iter().map(|w| w.to_string()).collect(),
            },
            [] => Reply::Value {
                key: String::new(),
                words: Vec::new(),
            },
        }
    }
}

/// The numbers of a position reply (`ABS_ACT_POS x y z a b c`, `JOINT_POS ...`): every
/// word after the key must be a finite number.
pub fn numbers(words: &[String]) -> Option<Vec<f64>> {
    words
        .iter()
        .map(|w| w.parse::<f64>().ok().filter(|v| v.is_finite()))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn split(chunks: &[&[u8]]) -> Vec<String> {
        let mut s = LineSplitter::new();
        let mut out = Vec::new();
        for c in chunks {
            s.feed(c, &mut out);
        }
        out.into_iter().map(|l| l.text).collect()
    }

    #[test]
    fn lines_end_at_any_run_of_cr_and_lf_whatever_the_chunking() {
        // What the shell sends: SET replies end "\n\r", get replies "\r\n".
        let bytes = b"SET MDI ACK\n\rABS_ACT_POS 1.000000 2.000000\r\nERROR OK\r\n";
        let whole = split(&[bytes]);
        assert_eq!(
            whole,
            ["SET MDI ACK", "ABS_ACT_POS 1.000000 2.000000", "ERROR OK"]
        );
        let bytewise: Vec<&[u8]> = bytes.chunks(1).collect();
        assert_eq!(split(&bytewise), whole);
        // A line not yet ended is kept for later.
        assert_eq!(split(&[b"SET ECHO"]), Vec::<String>::new());
    }

    #[test]
    fn an_endless_line_is_cut_and_marked() {
        let mut s = LineSplitter::new();
        let mut out = Vec::new();
        s.feed(&vec![b'x'; MAX_LINE + 10], &mut out);
        assert!(out.is_empty());
        s.feed(b"\r\nOK\r\n", &mut out);
        assert_eq!(out.len(), 2);
        assert_eq!(out[0].text.len(), MAX_LINE);
        assert!(out[0].cut);
        assert_eq!(out[1].text, "OK");
        assert!(!out[1].cut);
    }

    #[test]
    fn replies_are_read_as_the_shell_writes_them() {
        assert_eq!(
            Reply::parse("HELLO ACK EMCNETSVR 1.1"),
            Reply::HelloAck {
                server: "EMCNETSVR 1.1".into()
            }
        );
        assert_eq!(Reply::parse("HELLO NAK"), Reply::HelloNak);
        assert_eq!(
            Reply::parse("SET MDI ACK"),
            Reply::SetAck {
                command: "MDI".into()
            }
        );
        assert_eq!(
            Reply::parse("SET ENABLE NAK"),
            Reply::SetNak {
                command: "ENABLE".into()
            }
        );
        assert_eq!(
            Reply::parse("SET NAK"),
            Reply::SetNak {
                command: String::new()
            }
        );
        assert_eq!(
            Reply::parse("GET BOGUS NAK"),
            Reply::GetNak {
                key: "BOGUS".into()
            }
        );
        assert_eq!(
            Reply::parse("JOINT_HOMED NAK"),
            Reply::GetNak {
                key: "JOINT_HOMED".into()
            }
        );
        let Reply::Value { key, words } = Reply::parse("ABS_ACT_POS 1.5 -2.25 0 0 0 0") else {
            panic!("a value");
        };
        assert_eq!(key, "ABS_ACT_POS");
        assert_eq!(numbers(&words), Some(vec![1.5, -2.25, 0.0, 0.0, 0.0, 0.0]));
        assert_eq!(numbers(&["1".into(), "nan".into()]), None);
        assert_eq!(numbers(&["1".into(), "x".into()]), None);
    }
}
