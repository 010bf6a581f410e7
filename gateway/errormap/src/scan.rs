//! The scan: which points to measure, from which side, how often, and how the
//! measurements become a map.
//!
//! Design: a coarse grid over the travel (default every 10 mm) for the smooth errors and
//! the cross terms, plus one dense line along each axis through the middle of the
//! other (default every 1 mm: five points per 5 mm lead, enough for the ballscrew's
//! periodic error, which depends only on the nut's position along its own screw). Every
//! point is approached from below and then from above on both axes (backlash differs
//! per direction), and the whole plan is run `passes` times (default 1; more give every
//! node a mean and a dispersion; with one, the points the lines share with the grid give
//! the dispersion). On the 200 x 150 mm demo stage that is (21 x 16 + 201 + 151) x 2
//! sides = 1376 frames, against 120 000 for a dense 1 mm grid. Positions are put on the
//! stage's own steps ([`ScanPlan::on_steps`]) so the stage goes exactly where the plan
//! says. Errors are stored relative to the reference point measured at the start of
//! each run, so a scan resumed after a new homing (which moves the zero by a few um)
//! joins the first part seamlessly.

use crate::{Approach, Direction};
use protocol::errormap::{ErrorMap, Grid, Identity, Line, Measured, Node, Stat, SCHEMA};
use std::collections::BTreeMap;

/// How dense and how often.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScanSpec {
    pub grid_step_mm: f64,
    pub line_step_mm: f64,
    pub passes: u32,
}

impl Default for ScanSpec {
    fn default() -> Self {
        Self {
            grid_step_mm: 10.0,
            line_step_mm: 1.0,
            // One pass: on the stage's own steps a second pass halves only the settling
            // noise (0.08 um), at twice the machine time (issue 39: 347 s -> 175 s on
            // the demo stage, 0.31 -> 0.34 um rms after a homing, thermal drift off).
            passes: 1,
        }
    }
}

/// Where a measurement goes in the map.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Slot {
    Grid { i: usize, j: usize },
    XLine { k: usize },
    YLine { k: usize },
}

/// One measurement to take.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ScanPoint {
    pub command_mm: [f64; 2],
    pub dir: Direction,
    pub pass: u32,
    pub slot: Slot,
}

/// The plan of a scan over `lo..hi` (machine mm).
#[derive(Clone, Debug, PartialEq)]
pub struct ScanPlan {
    pub spec: ScanSpec,
    pub xs: Vec<f64>,
    pub ys: Vec<f64>,
    /// The dense line along X sits at this Y; the one along Y at this X.
    pub x_line_at: f64,
    pub y_line_at: f64,
    pub x_line: Vec<f64>,
    pub y_line: Vec<f64>,
    pub points: Vec<ScanPoint>,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ScanError {
    #[error("the scan area {lo:?}..{hi:?} mm is empty or not finite")]
    EmptyArea { lo: [f64; 2], hi: [f64; 2] },
    #[error("{what} must be a positive number of mm at most the area's size (got {value})")]
    BadStep { what: &'static str, value: f64 },
    #[error("passes must be 1 to 10 (got {0})")]
    BadPasses(u32),
    #[error("measurement #{0} is not in the plan")]
    NotInPlan(usize),
    #[error("measurement #{index}: {message}")]
    Impossible { index: usize, message: String },
    #[error("measurement #{0} again, with other values")]
    Conflicting(usize),
    #[error("the plan would take {frames:.0} frames; at most {MAX_SCAN_FRAMES} are accepted (a coarser step)")]
    TooManyFrames { frames: f64 },
}

/// The most frames one scan may take (a dense 1 mm grid over the demo stage is
/// 120 000): a plan is refused past it before anything is allocated.
pub const MAX_SCAN_FRAMES: u64 = 250_000;

/// How many positions [`positions`] gives, as a float (no overflow for any step).
fn position_count(lo: f64, hi: f64, step: f64) -> f64 {
    ((hi - lo) / step).ceil().max(1.0) + 1.0
}

/// The frames a scan of `spec` over `lo..hi` takes: (grid frames, dense-line frames),
/// computed without building the plan (floats: a tiny step gives a huge number, never
/// an overflow).
pub fn frames(lo: [f64; 2], hi: [f64; 2], spec: ScanSpec) -> (f64, f64) {
    let per_point = 2.0 * f64::from(spec.passes);
    let grid = position_count(lo[0], hi[0], spec.grid_step_mm)
        * position_count(lo[1], hi[1], spec.grid_step_mm);
    let lines = position_count(lo[0], hi[0], spec.line_step_mm)
        + position_count(lo[1], hi[1], spec.line_step_mm);
    (grid * per_point, lines * per_point)
}

/// Positions from `lo` to `hi` at most `step` apart, both ends included; with a
/// `resolution` (the stage's smallest step on this axis, mm; 0 for none) each position
/// is put on a multiple of it, the ends inward, so the stage goes exactly where the plan
/// says and a node's error is not off by the controller's rounding of its command (up to
/// half a step: 0.25 um on a 0.5 um encoder, the same at every pass, so no averaging
/// removes it).
fn positions(lo: f64, hi: f64, step: f64, resolution: f64) -> Vec<f64> {
    let n = ((hi - lo) / step).ceil().max(1.0) as usize;
    let snap = resolution > 0.0 && resolution.is_finite() && resolution * 4.0 <= step;
    (0..=n)
        .map(|k| {
            let v = lo + (hi - lo) * k as f64 / n as f64;
            if !snap {
                v
            } else if k == 0 {
                (lo / resolution).ceil() * resolution
            } else if k == n {
                (hi / resolution).floor() * resolution
            } else {
                (v / resolution).round() * resolution
            }
        })
        .collect()
}

impl ScanPlan {
    /// The plan with positions anywhere: [`ScanPlan::on_steps`] with no resolution.
    pub fn new(lo: [f64; 2], hi: [f64; 2], spec: ScanSpec) -> Result<Self, ScanError> {
        Self::on_steps(lo, hi, spec, [0.0; 2])
    }

    /// The plan with every position on a multiple of the stage's smallest step per axis
    /// (`resolution_mm`, the stage's encoder count or microstep; 0 or not finite: none),
    /// the area's ends rounded inward. Worked example: on a 0.5 um encoder a grid
    /// position 10.0510 mm becomes 10.0510 (already a multiple), 20.0499 mm becomes
    /// 20.0500, and the area's start 0.0513 mm becomes 0.0515.
    pub fn on_steps(
        lo: [f64; 2],
        hi: [f64; 2],
        spec: ScanSpec,
        resolution_mm: [f64; 2],
    ) -> Result<Self, ScanError> {
        if !(lo.iter().chain(&hi).all(|v| v.is_finite()) && hi[0] > lo[0] && hi[1] > lo[1]) {
            return Err(ScanError::EmptyArea { lo, hi });
        }
        let size = (hi[0] - lo[0]).min(hi[1] - lo[1]);
        for (what, v) in [
            ("the grid step", spec.grid_step_mm),
            ("the line step", spec.line_step_mm),
        ] {
            if !(v.is_finite() && v > 0.0 && v <= size) {
                return Err(ScanError::BadStep { what, value: v });
            }
        }
        if !(1..=10).contains(&spec.passes) {
            return Err(ScanError::BadPasses(spec.passes));
        }
        let (grid, lines) = frames(lo, hi, spec);
        if grid + lines > MAX_SCAN_FRAMES as f64 {
            return Err(ScanError::TooManyFrames {
                frames: grid + lines,
            });
        }
        let [rx, ry] = resolution_mm;
        let xs = positions(lo[0], hi[0], spec.grid_step_mm, rx);
        let ys = positions(lo[1], hi[1], spec.grid_step_mm, ry);
        let x_line = positions(lo[0], hi[0], spec.line_step_mm, rx);
        let y_line = positions(lo[1], hi[1], spec.line_step_mm, ry);
        let x_line_at = ys[ys.len() / 2];
        let y_line_at = xs[xs.len() / 2];
        let mut points = Vec::new();
        for pass in 0..spec.passes {
            let mut visit = |p: [f64; 2], slot: Slot| {
                for dir in [Direction::FORWARD, Direction::REVERSE] {
                    points.push(ScanPoint {
                        command_mm: p,
                        dir,
                        pass,
                        slot,
                    });
                }
            };
            // Serpentine over the grid: short moves between neighbours.
            for (j, &y) in ys.iter().enumerate() {
                for n in 0..xs.len() {
                    let i = if j % 2 == 0 { n } else { xs.len() - 1 - n };
                    visit([xs[i], y], Slot::Grid { i, j });
                }
            }
            for (k, &x) in x_line.iter().enumerate() {
                visit([x, x_line_at], Slot::XLine { k });
            }
            for (k, &y) in y_line.iter().enumerate() {
                visit([y_line_at, y], Slot::YLine { k });
            }
        }
        Ok(Self {
            spec,
            xs,
            ys,
            x_line_at,
            y_line_at,
            x_line,
            y_line,
            points,
        })
    }

    /// A fingerprint of the plan, so a resumed scan continues only the same plan.
    pub fn fingerprint(&self) -> String {
        format!(
            "grid {}x{} {:.4}..{:.4} x {:.4}..{:.4}, lines {} at y {:.4} and {} at x {:.4}, {} passes",
            self.xs.len(),
            self.ys.len(),
            self.xs[0],
            self.xs[self.xs.len() - 1],
            self.ys[0],
            self.ys[self.ys.len() - 1],
            self.x_line.len(),
            self.x_line_at,
            self.y_line.len(),
            self.y_line_at,
            self.spec.passes
        )
    }
}

/// One measurement: the camera's error at a plan point (relative to the reference
/// measured at the start of its run), um, and the yaw relative to it, urad.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    pub error_um: [f64; 2],
    pub yaw_urad: f64,
}

/// The journal of a scan under way: a header line naming what the samples belong to,
/// then one line per sample, each line a JSON object closed by its own checksum:
///
/// ```text
/// {"journal": "gateway scan journal 2", "job": "demo.toml", "machine": "...", "controller": "...", "board": "...", "certificate_sha256": "...", "camera": "...", "plan": "grid 21x16 ...", "crc": "5f0e2a91"}
/// {"i": 17, "ex": 1.2, "ey": -0.4, "yaw": 3.1, "crc": "0c4d7a2e"}
/// ```
///
/// `crc` is the CRC-32 (IEEE 802.3, as zlib and PNG) of the line's bytes before
/// `, "crc"`; a line is whole only when it ends with a newline and its checksum matches.
/// A stopped scan resumes from the whole lines: the bytes after the last newline (the
/// process died while writing a line) are a torn tail, cut off before anything more is
/// appended (so is a whole last line whose checksum fails when nothing follows it: the
/// power went before its blocks were all written); any other damage is refused naming
/// the line. A journal resumes only for the same job, machine, controller, board (and
/// certificate), camera and plan (the error names the first field that differs); a
/// sample is refused when its index is not
/// in the plan, when it repeats an index with other values (an identical repeat is
/// taken once), or when a value is not finite or beyond what a stage can do (an error of
/// more than [`MAX_ERROR_UM`], a yaw of more than [`MAX_YAW_URAD`]).
pub mod journal {
    use super::{Sample, ScanPlan};
    use protocol::errormap::Identity;
    use std::collections::BTreeMap;

    /// The format's name, the header's first field.
    pub const FORMAT: &str = "gateway scan journal 2";
    /// The largest error a sample may have, um: a camera error of more than 1 mm relative
    /// to the reference is a misread board (a pitch off), not a stage's error.
    pub const MAX_ERROR_UM: f64 = 1000.0;
    /// The largest yaw a sample may have relative to the reference, urad (0.1 rad).
    pub const MAX_YAW_URAD: f64 = 100_000.0;
    /// How the header begins; a file without a whole line that is a prefix of this (or
    /// begins with it) is a header cut while it was written: nothing was kept yet.
    const HEAD: &str = "{\"journal\": \"gateway scan journal";
    const CRC: &str = ", \"crc\": \"";

    /// CRC-32 (IEEE 802.3, reflected, polynomial 0xEDB88320): zlib's, PNG's.
    pub fn crc32(bytes: &[u8]) -> u32 {
        const TABLE: [u32; 256] = {
            let mut t = [0u32; 256];
            let mut n = 0;
            while n < 256 {
                let mut c = n as u32;
                let mut k = 0;
                while k < 8 {
                    c = if c & 1 != 0 {
                        0xEDB8_8320 ^ (c >> 1)
                    } else {
                        c >> 1
                    };
                    k += 1;
                }
                t[n] = c;
                n += 1;
            }
            t
        };
        !bytes.iter().fold(!0u32, |c, &b| {
            TABLE[((c ^ u32::from(b)) & 0xff) as usize] ^ (c >> 8)
        })
    }

    /// `body` (a JSON object without its closing brace) closed with its checksum.
    fn sealed(body: String) -> String {
        let crc = crc32(body.as_bytes());
        format!("{body}{CRC}{crc:08x}\"}}\n")
    }

    /// What a journal belongs to.
    #[derive(Clone, Debug, PartialEq, Eq)]
    pub struct Header {
        /// The job (its file name).
        pub job: String,
        pub identity: Identity,
        /// The plan's fingerprint ([`ScanPlan::fingerprint`]).
        pub plan: String,
    }

    impl Header {
        pub fn new(job: &str, identity: Identity, plan: &ScanPlan) -> Self {
            Self {
                job: job.to_string(),
                identity,
                plan: plan.fingerprint(),
            }
        }

        fn fields(&self) -> [(&'static str, &str); 7] {
            let i = &self.identity;
            [
                ("job", &self.job),
                ("machine", &i.machine),
                ("controller", &i.controller),
                ("board", &i.board),
                ("certificate_sha256", &i.certificate_sha256),
                ("camera", &i.camera),
                ("plan", &self.plan),
            ]
        }

        /// The header line, newline included.
        pub fn line(&self) -> String {
            let mut body = format!("{{\"journal\": {}", quote(FORMAT));
            for (k, v) in self.fields() {
                body.push_str(&format!(", \"{k}\": {}", quote(v)));
            }
            sealed(body)
        }
    }

    /// The line of one sample, newline included.
    pub fn line(index: usize, s: &Sample) -> String {
        sealed(format!(
            "{{\"i\": {index}, \"ex\": {:?}, \"ey\": {:?}, \"yaw\": {:?}",
            s.error_um[0], s.error_um[1], s.yaw_urad
        ))
    }

    /// What a journal holds.
    #[derive(Clone, Debug, PartialEq)]
    pub struct Journal {
        /// The samples, in the order they were written (an identical repeat once).
        pub samples: Vec<(usize, Sample)>,
        /// The bytes of the whole lines, from the start: what is kept. 0 when not even
        /// the header is whole (the file holds no sample: it is started anew).
        pub whole_bytes: usize,
        /// The bytes after the kept lines (a line cut while it was written, or a last
        /// line whose checksum fails), to cut off before anything is appended.
        pub torn_bytes: usize,
    }

    /// The journal in `bytes`, checked against what this scan is (`want`) and its plan.
    pub fn read(want: &Header, plan: &ScanPlan, bytes: &[u8]) -> Result<Journal, String> {
        let whole = bytes.iter().rposition(|&b| b == b'\n').map_or(0, |k| k + 1);
        let torn_bytes = bytes.len() - whole;
        if whole == 0 {
            let n = bytes.len().min(HEAD.len());
            if bytes[..n] != HEAD.as_bytes()[..n] {
                return Err(
                    "it is not a scan journal (its first bytes are not a journal's header)".into(),
                );
            }
            return Ok(Journal {
                samples: Vec::new(),
                whole_bytes: 0,
                torn_bytes,
            });
        }
        let mut lines = bytes[..whole - 1].split(|&b| b == b'\n');
        let head = lines.next().unwrap_or_default();
        if head.starts_with(b"{\"plan\": ") {
            return Err("it was written by an older gateway, without a checksum per line or the machine's identity: it cannot be checked, so it is not resumed".into());
        }
        let head = body(head).map_err(|e| format!("line 1 (the header): {e}"))?;
        let got = parse_header(head).map_err(|e| format!("line 1 (the header): {e}"))?;
        for ((what, a), (_, b)) in got.fields().into_iter().zip(want.fields()) {
            if a != b {
                return Err(format!(
                    "it is the journal of another scan: its {what} is `{a}`, this scan's is `{b}`"
                ));
            }
        }
        let mut seen: BTreeMap<usize, (Sample, usize)> = BTreeMap::new();
        let mut samples = Vec::new();
        let lines: Vec<&[u8]> = lines.collect();
        let (mut whole, mut torn_bytes) = (whole, torn_bytes);
        for (k, l) in lines.iter().enumerate() {
            let n = k + 2;
            let b = match body(l) {
                Ok(b) => b,
                // The last line, written but not yet on the disk when the power went
                // (its blocks partly written, its newline there): torn as well, when
                // nothing follows it. It is measured again; any earlier line is damage.
                Err(_) if k + 1 == lines.len() && torn_bytes == 0 => {
                    whole -= l.len() + 1;
                    torn_bytes = l.len() + 1;
                    break;
                }
                Err(e) => return Err(format!("line {n}: {e}")),
            };
            let (index, s) = parse_sample(b, plan).map_err(|e| format!("line {n}: {e}"))?;
            match seen.get(&index) {
                Some((first, _)) if *first == s => {}
                Some((_, at)) => {
                    return Err(format!(
                        "line {n}: sample #{index} again with other values than on line {at}"
                    ))
                }
                None => {
                    seen.insert(index, (s, n));
                    samples.push((index, s));
                }
            }
        }
        Ok(Journal {
            samples,
            whole_bytes: whole,
            torn_bytes,
        })
    }

    /// A whole line's text before its checksum field, once the checksum matches.
    fn body(line: &[u8]) -> Result<&str, String> {
        let text = std::str::from_utf8(line).map_err(|_| "not UTF-8 text (damaged)")?;
        let damaged = || format!("`{}` is damaged (no checksum)", shown(text));
        let at = text.rfind(CRC).ok_or_else(damaged)?;
        let hex = text[at + CRC.len()..]
            .strip_suffix("\"}")
            .filter(|h| h.len() == 8)
            .ok_or_else(damaged)?;
        let crc = u32::from_str_radix(hex, 16).map_err(|_| damaged())?;
        let body = &text[..at];
        if crc32(body.as_bytes()) != crc {
            return Err(format!(
                "`{}` is damaged (its checksum does not match)",
                shown(text)
            ));
        }
        Ok(body)
    }

    /// At most 120 characters of a line, for a message.
    fn shown(text: &str) -> String {
        match text.char_indices().nth(120) {
            Some((at, _)) => format!("{}...", &text[..at]),
            None => text.to_string(),
        }
    }

    /// `key: value` pairs of a flat JSON object written by this module (no closing
    /// brace: the checksum field was taken off); values are strings or numbers.
    fn pairs(body: &str) -> Result<Vec<(String, Value)>, String> {
        let mut rest = body
            .strip_prefix('{')
            .ok_or("not a journal line (no `{`)")?;
        let mut out = Vec::new();
        loop {
            let (key, after) = string(rest.trim_start())?;
            let after = after
                .trim_start()
                .strip_prefix(':')
                .ok_or_else(|| format!("no `:` after `{key}`"))?
                .trim_start();
            let (value, after) = if after.starts_with('"') {
                let (s, a) = string(after)?;
                (Value::Str(s), a)
            } else {
                let end = after.find(',').unwrap_or(after.len());
                (Value::Num(after[..end].trim().to_string()), &after[end..])
            };
            out.push((key, value));
            match after.trim_start().strip_prefix(',') {
                Some(a) => rest = a,
                None if after.trim().is_empty() => return Ok(out),
                None => return Err(format!("`{}` after a value", shown(after))),
            }
        }
    }

    enum Value {
        Str(String),
        Num(String),
    }

    /// A JSON string as [`quote`] writes it, and what follows it.
    fn string(s: &str) -> Result<(String, &str), String> {
        let mut chars = s
            .strip_prefix('"')
            .ok_or("a key or text without its `\"`")?
            .char_indices();
        let mut out = String::new();
        while let Some((k, c)) = chars.next() {
            match c {
                '"' => return Ok((out, &s[k + 2..])),
                '\\' => match chars.next().map(|(_, c)| c) {
                    Some('"') => out.push('"'),
                    Some('\\') => out.push('\\'),
                    Some('u') => {
                        let hex: String = (0..4)
                            .filter_map(|_| chars.next())
                            .map(|(_, c)| c)
                            .collect();
                        let c = u32::from_str_radix(&hex, 16)
                            .ok()
                            .and_then(char::from_u32)
                            .ok_or("a bad `\\u` escape")?;
                        out.push(c);
                    }
                    _ => return Err("a bad escape in a text".into()),
                },
                c => out.push(c),
            }
        }
        Err("a text without its closing `\"`".into())
    }

    /// `s` as a JSON string: quotes, backslashes and control characters escaped.
    fn quote(s: &str) -> String {
        let mut out = String::from('"');
        for c in s.chars() {
            match c {
                '"' => out.push_str("\\\""),
                '\\' => out.push_str("\\\\"),
                c if (c as u32) < 0x20 || c == '\u{7f}' => {
                    out.push_str(&format!("\\u{:04x}", c as u32))
                }
                c => out.push(c),
            }
        }
        out.push('"');
        out
    }

    fn parse_header(body: &str) -> Result<Header, String> {
        let pairs = pairs(body)?;
        let text = |key: &str| -> Result<String, String> {
            match pairs.iter().find(|(k, _)| k == key) {
                Some((_, Value::Str(s))) => Ok(s.clone()),
                Some(_) => Err(format!("`{key}` is not a text")),
                None => Err(format!("no `{key}`")),
            }
        };
        let format = text("journal")?;
        if format != FORMAT {
            return Err(format!("the format `{format}` is not `{FORMAT}`"));
        }
        if pairs.len() != 8 {
            return Err("the header has other fields than a journal's".into());
        }
        Ok(Header {
            job: text("job")?,
            identity: Identity {
                machine: text("machine")?,
                controller: text("controller")?,
                board: text("board")?,
                certificate_sha256: text("certificate_sha256")?,
                camera: text("camera")?,
            },
            plan: text("plan")?,
        })
    }

    fn parse_sample(body: &str, plan: &ScanPlan) -> Result<(usize, Sample), String> {
        let pairs = pairs(body)?;
        let field = |key: &str| -> Result<&str, String> {
            match pairs.iter().find(|(k, _)| k == key) {
                Some((_, Value::Num(v))) => Ok(v),
                Some(_) => Err(format!("`{key}` is not a number")),
                None => Err(format!("no `{key}` (not a sample)")),
            }
        };
        if pairs.len() != 4 {
            return Err("a sample has the fields i, ex, ey and yaw only".into());
        }
        let index: usize = field("i")?
            .parse()
            .map_err(|_| format!("`i` is `{}`, not an index", field("i").unwrap_or("")))?;
        if index >= plan.points.len() {
            return Err(format!(
                "sample #{index} is not in the plan (it has {} points)",
                plan.points.len()
            ));
        }
        let value = |key: &str, bound: f64, unit: &str| -> Result<f64, String> {
            let text = field(key)?;
            let v: f64 = text
                .parse()
                .map_err(|_| format!("`{key}` is `{text}`, not a number"))?;
            if !v.is_finite() || v.abs() > bound {
                return Err(format!(
                    "`{key}` is {text} {unit}: impossible (a finite value of at most {bound} {unit} in size)"
                ));
            }
            Ok(v)
        };
        Ok((
            index,
            Sample {
                error_um: [
                    value("ex", MAX_ERROR_UM, "um")?,
                    value("ey", MAX_ERROR_UM, "um")?,
                ],
                yaw_urad: value("yaw", MAX_YAW_URAD, "urad")?,
            },
        ))
    }

    /// Whether a sample is possible: finite, an error of at most [`MAX_ERROR_UM`] and a
    /// yaw of at most [`MAX_YAW_URAD`]; the error names the field.
    pub fn check_sample(s: &Sample) -> Result<(), String> {
        for (key, v, bound, unit) in [
            ("ex", s.error_um[0], MAX_ERROR_UM, "um"),
            ("ey", s.error_um[1], MAX_ERROR_UM, "um"),
            ("yaw", s.yaw_urad, MAX_YAW_URAD, "urad"),
        ] {
            if !v.is_finite() || v.abs() > bound {
                return Err(format!(
                    "{key} = {v:?} {unit} is impossible (a finite value of at most {bound} {unit} in size)"
                ));
            }
        }
        Ok(())
    }
}

/// Collects samples by plan index and turns them into a map.
#[derive(Clone, Debug, Default)]
pub struct MapBuilder {
    samples: BTreeMap<usize, Sample>,
}

impl MapBuilder {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn record(&mut self, plan: &ScanPlan, index: usize, s: Sample) -> Result<(), ScanError> {
        if index >= plan.points.len() {
            return Err(ScanError::NotInPlan(index));
        }
        journal::check_sample(&s).map_err(|message| ScanError::Impossible { index, message })?;
        // The same measurement twice is taken once; two different ones cannot both be.
        match self.samples.get(&index) {
            Some(had) if *had != s => return Err(ScanError::Conflicting(index)),
            _ => {
                self.samples.insert(index, s);
            }
        }
        Ok(())
    }

    pub fn is_done(&self, index: usize) -> bool {
        self.samples.contains_key(&index)
    }

    pub fn done(&self) -> usize {
        self.samples.len()
    }

    /// The map, once every point of the plan has a sample (None before).
    #[allow(clippy::too_many_arguments)]
    pub fn finish(
        &self,
        plan: &ScanPlan,
        identity: Identity,
        version: u32,
        created: String,
        tool_offset_mm: [f64; 2],
        board_at_machine_zero_mm: [f64; 2],
        reference_mm: [f64; 2],
    ) -> Option<ErrorMap> {
        if self.samples.len() != plan.points.len() {
            return None;
        }
        // Every sample of one slot and direction, over the passes.
        let mut by: BTreeMap<(Slot, bool), Vec<Sample>> = BTreeMap::new();
        for (k, p) in plan.points.iter().enumerate() {
            let forward = p.dir.x == Approach::Forward;
            by.entry((p.slot, forward))
                .or_default()
                .push(self.samples[&k]);
        }
        let measured = |v: &[Sample]| {
            let col = |f: fn(&Sample) -> f64| {
                Stat::of(&v.iter().map(f).collect::<Vec<_>>()).expect("at least one pass")
            };
            Measured {
                ex_um: col(|s| s.error_um[0]),
                ey_um: col(|s| s.error_um[1]),
                yaw_urad: col(|s| s.yaw_urad),
            }
        };
        let node = |slot: Slot| Node {
            forward: measured(&by[&(slot, true)]),
            reverse: measured(&by[&(slot, false)]),
        };
        let nodes = (0..plan.ys.len())
            .flat_map(|j| (0..plan.xs.len()).map(move |i| Slot::Grid { i, j }))
            .map(node)
            .collect::<Vec<_>>();
        let x_nodes = (0..plan.x_line.len())
            .map(|k| node(Slot::XLine { k }))
            .collect();
        let y_nodes = (0..plan.y_line.len())
            .map(|k| node(Slot::YLine { k }))
            .collect();
        // Expanded (k = 2) uncertainty of a node's mean: the RMS over nodes of the
        // standard error of both components.
        // With one pass there is no dispersion within a node: the points the dense
        // lines share with the grid's middle row and column were measured twice, apart
        // in time, and their differences give it (each difference has twice a single
        // measurement's variance).
        let se2: Vec<f64> = if plan.spec.passes > 1 {
            by.values()
                .map(|v| {
                    let m = measured(v);
                    let n = f64::from(m.ex_um.n);
                    (m.ex_um.sd.powi(2) + m.ey_um.sd.powi(2)) / n
                })
                .collect()
        } else {
            shared_nodes(plan)
                .into_iter()
                .flat_map(|(grid, line)| [(grid, line, true), (grid, line, false)])
                .map(|(grid, line, forward)| {
                    let (a, b) = (by[&(grid, forward)][0], by[&(line, forward)][0]);
                    ((a.error_um[0] - b.error_um[0]).powi(2)
                        + (a.error_um[1] - b.error_um[1]).powi(2))
                        / 2.0
                })
                .collect()
        };
        let uncertainty_um = if se2.is_empty() {
            0.0
        } else {
            2.0 * (se2.iter().sum::<f64>() / se2.len() as f64).sqrt()
        };
        Some(ErrorMap {
            schema: SCHEMA.into(),
            version,
            created,
            identity,
            tool_offset_mm,
            board_at_machine_zero_mm,
            reference_mm,
            grid: Grid {
                xs: plan.xs.clone(),
                ys: plan.ys.clone(),
                nodes,
            },
            x_lines: vec![Line {
                at_mm: plan.x_line_at,
                positions: plan.x_line.clone(),
                nodes: x_nodes,
            }],
            y_lines: vec![Line {
                at_mm: plan.y_line_at,
                positions: plan.y_line.clone(),
                nodes: y_nodes,
            }],
            uncertainty_um,
        })
    }
}

/// The grid nodes a dense line also measured (the line's position equal to the node's,
/// within a nanometre): (grid slot, line slot).
fn shared_nodes(plan: &ScanPlan) -> Vec<(Slot, Slot)> {
    let same = |a: f64, b: f64| (a - b).abs() < 1e-6;
    let mut pairs = Vec::new();
    if let Some(j) = plan.ys.iter().position(|&y| same(y, plan.x_line_at)) {
        for (i, &x) in plan.xs.iter().enumerate() {
            if let Some(k) = plan.x_line.iter().position(|&v| same(v, x)) {
                pairs.push((Slot::Grid { i, j }, Slot::XLine { k }));
            }
        }
    }
    if let Some(i) = plan.xs.iter().position(|&x| same(x, plan.y_line_at)) {
        for (j, &y) in plan.ys.iter().enumerate() {
            if let Some(k) = plan.y_line.iter().position(|&v| same(v, y)) {
                pairs.push((Slot::Grid { i, j }, Slot::YLine { k }));
            }
        }
    }
    pairs
}

/// The stage as it names itself, without where it is connected (a port, a bus), which
/// may change between the scan and its use.
pub fn without_link(name: &str) -> String {
    let cut = [" at /", " on ", " at "]
        .iter()
        .filter_map(|m| name.find(m))
        .min()
        .unwrap_or(name.len());
    // The GRBL driver names itself `GRBL 1.1h (GRBL at /dev/ttyUSB0)`: a bracket
    // opened before the link goes with it.
    let cut = match name[..cut].rfind(" (") {
        Some(open) if !name[open..cut].contains(')') && cut < name.len() => open,
        _ => cut,
    };
    name[..cut].trim_end().to_string()
}

/// RFC 3339 UTC time of `t`, to the second (chrono's formatting).
pub fn rfc3339(t: std::time::SystemTime) -> String {
    chrono::DateTime::<chrono::Utc>::from(t).to_rfc3339_opts(chrono::SecondsFormat::Secs, true)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::MapModel;

    #[test]
    fn the_default_plan_of_the_demo_stage_stays_under_1500_frames() {
        let plan = ScanPlan::new([0.1, 0.1], [199.9, 149.9], ScanSpec::default()).unwrap();
        assert_eq!((plan.xs.len(), plan.ys.len()), (21, 16));
        assert!(plan.xs.windows(2).all(|w| w[1] - w[0] <= 10.0));
        assert!(plan.x_line.windows(2).all(|w| w[1] - w[0] <= 1.0));
        assert_eq!(plan.points.len(), (21 * 16 + 201 + 151) * 2);
        assert!(plan.points.len() <= 1500);
        // Each point from below and from above, in that order.
        assert_eq!(plan.points[0].dir, Direction::FORWARD);
        assert_eq!(plan.points[1].dir, Direction::REVERSE);
        assert_eq!(plan.points[0].command_mm, plan.points[1].command_mm);
    }

    fn small_plan() -> ScanPlan {
        ScanPlan::new(
            [0.0, 0.0],
            [10.0, 10.0],
            ScanSpec {
                grid_step_mm: 5.0,
                line_step_mm: 5.0,
                passes: 1,
            },
        )
        .unwrap()
    }

    fn identity() -> Identity {
        Identity {
            machine: "sim \"XY\" \\ stage\tµ".into(),
            controller: "sim".into(),
            board: "b".into(),
            certificate_sha256: "00ff".into(),
            camera: "cam".into(),
        }
    }

    fn sample(k: usize) -> Sample {
        Sample {
            error_um: [k as f64 * 0.37 - 2.0, -(k as f64) / 3.0],
            yaw_urad: 1e-3 * k as f64,
        }
    }

    /// The journal of every point of the small plan.
    fn whole_journal(header: &journal::Header, plan: &ScanPlan) -> String {
        let mut text = header.line();
        for k in 0..plan.points.len() {
            text.push_str(&journal::line(k, &sample(k)));
        }
        text
    }

    #[test]
    fn the_checksum_is_crc32() {
        assert_eq!(journal::crc32(b"123456789"), 0xCBF4_3926);
        assert_eq!(journal::crc32(b""), 0);
    }

    #[test]
    fn the_journal_round_trips_and_belongs_to_its_job_machine_and_plan() {
        let plan = small_plan();
        let header = journal::Header::new("job.toml", identity(), &plan);
        let s = sample(1);
        let text = header.line() + &journal::line(3, &s) + &journal::line(4, &s);
        let read = journal::read(&header, &plan, text.as_bytes()).unwrap();
        assert_eq!(read.samples, vec![(3, s), (4, s)]);
        assert_eq!((read.whole_bytes, read.torn_bytes), (text.len(), 0));
        // Every field of the header is checked, naming the first that differs.
        let other = ScanPlan::new([0.0, 0.0], [10.0, 10.0], ScanSpec::default()).unwrap();
        let e = journal::read(
            &journal::Header::new("job.toml", identity(), &other),
            &other,
            text.as_bytes(),
        )
        .unwrap_err();
        assert!(e.contains("its plan is"), "{e}");
        let e = journal::read(
            &journal::Header::new("other.toml", identity(), &plan),
            &plan,
            text.as_bytes(),
        )
        .unwrap_err();
        assert!(
            e.contains("its job is `job.toml`, this scan's is `other.toml`"),
            "{e}"
        );
        for (what, change) in [
            (
                "machine",
                (|i: &mut Identity| i.machine = "other".into()) as fn(&mut Identity),
            ),
            ("controller", |i| i.controller = "other".into()),
            ("board", |i| i.board = "other".into()),
            ("certificate_sha256", |i| {
                i.certificate_sha256 = "other".into()
            }),
            ("camera", |i| i.camera = "other".into()),
        ] {
            let mut id = identity();
            change(&mut id);
            let e = journal::read(
                &journal::Header::new("job.toml", id, &plan),
                &plan,
                text.as_bytes(),
            )
            .unwrap_err();
            assert!(
                e.contains(&format!("its {what} is `")) && e.contains("this scan's is `other`"),
                "{e}"
            );
        }
    }

    #[test]
    fn damage_duplicates_and_impossible_values_are_refused_naming_the_line() {
        let plan = small_plan();
        let header = journal::Header::new("job.toml", identity(), &plan);
        let read = |text: &str| journal::read(&header, &plan, text.as_bytes());
        let (a, b) = (journal::line(3, &sample(3)), journal::line(4, &sample(4)));
        // A damaged line before the last is refused.
        let e = read(&(header.line() + "garbage\n" + &b)).unwrap_err();
        assert!(e.starts_with("line 2: `garbage` is damaged"), "{e}");
        let flipped = a.replace("\"ex\": ", "\"ex\": 1");
        let e = read(&(header.line() + &flipped + &b)).unwrap_err();
        assert!(
            e.contains("line 2") && e.contains("checksum does not match"),
            "{e}"
        );
        // A damaged last line (its newline written, its blocks not all) is cut as a torn
        // one, unless a torn line follows it (it was whole before that one was begun).
        let text = header.line() + &a + &flipped;
        let r = read(&text).unwrap();
        assert_eq!(r.samples, vec![(3, sample(3))]);
        assert_eq!(
            (r.whole_bytes, r.torn_bytes),
            (text.len() - flipped.len(), flipped.len())
        );
        let r = read(&(header.line() + &a + &"\0".repeat(40) + "\n")).unwrap();
        assert_eq!(r.samples, vec![(3, sample(3))]);
        let e = read(&(header.line() + &flipped + "{\"i\": 4")).unwrap_err();
        assert!(
            e.contains("line 2") && e.contains("checksum does not match"),
            "{e}"
        );
        // A damaged header.
        let e = read(&(header.line().replace("job.toml", "job.tomm") + &a)).unwrap_err();
        assert!(
            e.contains("line 1 (the header)") && e.contains("checksum"),
            "{e}"
        );
        // An identical repeat is taken once; a conflicting one is refused.
        let r = read(&(header.line() + &a + &b + &a)).unwrap();
        assert_eq!(r.samples, vec![(3, sample(3)), (4, sample(4))]);
        let e = read(&(header.line() + &a + &b + &journal::line(3, &sample(5)))).unwrap_err();
        assert_eq!(
            e,
            "line 4: sample #3 again with other values than on line 2"
        );
        // Impossible values, each named with its line and field (checksums right).
        for (s, field) in [
            (
                Sample {
                    error_um: [1e300, 0.0],
                    yaw_urad: 0.0,
                },
                "`ex` is 1e300 um: impossible",
            ),
            (
                Sample {
                    error_um: [0.0, -1000.5],
                    yaw_urad: 0.0,
                },
                "`ey` is -1000.5 um: impossible",
            ),
            (
                Sample {
                    error_um: [0.0, f64::NAN],
                    yaw_urad: 0.0,
                },
                "`ey` is NaN um: impossible",
            ),
            (
                Sample {
                    error_um: [0.0, 0.0],
                    yaw_urad: f64::INFINITY,
                },
                "`yaw` is inf urad: impossible",
            ),
            (
                Sample {
                    error_um: [0.0, 0.0],
                    yaw_urad: -2e5,
                },
                "`yaw` is -200000.0 urad: impossible",
            ),
        ] {
            let e = read(&(header.line() + &a + &journal::line(7, &s))).unwrap_err();
            assert!(e.starts_with("line 3: ") && e.contains(field), "{e}");
        }
        let e = read(&(header.line() + &journal::line(plan.points.len(), &sample(0)))).unwrap_err();
        assert!(
            e.starts_with("line 2: sample #30 is not in the plan"),
            "{e}"
        );
        // A journal of an older gateway (no checksums, no identity).
        let e = read("{\"plan\": \"grid\"}\n{\"i\": 0, \"ex\": 0.0, \"ey\": 0.0, \"yaw\": 0.0}\n")
            .unwrap_err();
        assert!(e.contains("older gateway"), "{e}");
        // Another file altogether.
        assert!(read("hello").unwrap_err().contains("not a scan journal"));
        // The builder refuses what the reader refuses.
        let mut builder = MapBuilder::new();
        let e = builder
            .record(
                &plan,
                2,
                Sample {
                    error_um: [1e300, 0.0],
                    yaw_urad: 0.0,
                },
            )
            .unwrap_err();
        assert!(
            e.to_string()
                .contains("measurement #2: ex = 1e300 um is impossible"),
            "{e}"
        );
        builder.record(&plan, 2, sample(2)).unwrap();
        builder.record(&plan, 2, sample(2)).unwrap();
        assert_eq!(
            builder.record(&plan, 2, sample(3)),
            Err(ScanError::Conflicting(2))
        );
    }

    #[test]
    fn a_journal_cut_at_any_byte_keeps_exactly_its_whole_lines() {
        let plan = small_plan();
        let header = journal::Header::new("job.toml", identity(), &plan);
        let text = whole_journal(&header, &plan);
        let ends: Vec<usize> = text.match_indices('\n').map(|(k, _)| k + 1).collect();
        for cut in 0..=text.len() {
            let r = journal::read(&header, &plan, &text.as_bytes()[..cut])
                .unwrap_or_else(|e| panic!("cut at {cut}: {e}"));
            // The whole lines before the cut, and nothing else.
            let whole = ends
                .iter()
                .copied()
                .filter(|&e| e <= cut)
                .max()
                .unwrap_or(0);
            assert_eq!(
                (r.whole_bytes, r.torn_bytes),
                (whole, cut - whole),
                "cut at {cut}"
            );
            let lines = ends.iter().filter(|&&e| e <= cut).count();
            let want: Vec<_> = (0..lines.saturating_sub(1))
                .map(|k| (k, sample(k)))
                .collect();
            assert_eq!(r.samples, want, "cut at {cut}");
        }
    }

    #[test]
    fn bad_specs_are_refused() {
        let s = ScanSpec {
            grid_step_mm: 0.0,
            ..Default::default()
        };
        assert!(ScanPlan::new([0.0; 2], [10.0; 2], s).is_err());
        let s = ScanSpec {
            passes: 0,
            ..Default::default()
        };
        assert!(matches!(
            ScanPlan::new([0.0; 2], [10.0; 2], s),
            Err(ScanError::BadPasses(0))
        ));
        assert!(ScanPlan::new([5.0, 0.0], [5.0, 10.0], ScanSpec::default()).is_err());
    }

    #[test]
    fn a_plan_on_the_stage_steps_puts_every_position_on_a_step_inside_the_area() {
        let (lo, hi) = ([0.0513, 0.0513], [199.9487, 149.9487]);
        let plan = ScanPlan::on_steps(lo, hi, ScanSpec::default(), [0.0005, 0.001]).unwrap();
        for (axis, step, all) in [
            (0, 0.0005, [&plan.xs, &plan.x_line]),
            (1, 0.001, [&plan.ys, &plan.y_line]),
        ] {
            for v in all.into_iter().flatten() {
                let k = v / step;
                assert!(
                    (k - k.round()).abs() < 1e-6,
                    "{v} is not on a {step} mm step"
                );
                assert!(*v >= lo[axis] && *v <= hi[axis], "{v} outside the area");
            }
        }
        // The worked example of `on_steps`: the start rounded inward to 0.0515 mm.
        assert!((plan.xs[0] - 0.0515).abs() < 1e-12);
        assert!((plan.ys[0] - 0.052).abs() < 1e-12);
        // Still at most a step apart, and the same count as without steps.
        let free = ScanPlan::new(lo, hi, ScanSpec::default()).unwrap();
        assert_eq!(plan.points.len(), free.points.len());
        assert!(plan.xs.windows(2).all(|w| w[1] - w[0] <= 10.0 + 0.0005));
        // No resolution known: positions as before.
        assert_eq!(
            ScanPlan::on_steps(lo, hi, ScanSpec::default(), [0.0, f64::NAN]).unwrap(),
            free
        );
    }

    #[test]
    fn one_pass_takes_its_dispersion_from_the_points_lines_and_grid_share() {
        let spec = ScanSpec {
            grid_step_mm: 5.0,
            line_step_mm: 2.5,
            passes: 1,
        };
        let plan = ScanPlan::new([0.0, 0.0], [10.0, 10.0], spec).unwrap();
        let mut b = MapBuilder::new();
        for (k, p) in plan.points.iter().enumerate() {
            // The lines read 0.3 um more in X than the grid at the same point.
            let on_line = !matches!(p.slot, Slot::Grid { .. });
            let e = [0.1 * p.command_mm[0] + if on_line { 0.3 } else { 0.0 }, 0.0];
            let s = Sample {
                error_um: e,
                yaw_urad: 0.0,
            };
            b.record(&plan, k, s).unwrap();
        }
        let id = Identity {
            machine: "m".into(),
            controller: "c".into(),
            board: "b".into(),
            certificate_sha256: String::new(),
            camera: "cam".into(),
        };
        let map = b
            .finish(&plan, id, 1, "t".into(), [0.0; 2], [5.0; 2], [5.0; 2])
            .expect("complete");
        // Each shared point differs by 0.3 um: a single measurement's variance is
        // 0.3^2 / 2, and k = 2.
        assert_eq!(shared_nodes(&plan).len(), 3 + 3);
        assert!((map.uncertainty_um - 2.0 * (0.09f64 / 2.0).sqrt()).abs() < 1e-9);
    }

    #[test]
    fn samples_become_a_map_with_means_and_dispersions() {
        let spec = ScanSpec {
            grid_step_mm: 5.0,
            line_step_mm: 2.5,
            passes: 2,
        };
        let plan = ScanPlan::new([0.0, 0.0], [10.0, 10.0], spec).unwrap();
        let mut b = MapBuilder::new();
        for (k, p) in plan.points.iter().enumerate() {
            // 0.1 um/mm slope, 6 um backlash in reverse, +-0.2 um between passes.
            let back = if p.dir.x == Approach::Reverse {
                6.0
            } else {
                0.0
            };
            let wobble = if p.pass == 0 { 0.2 } else { -0.2 };
            let e = [
                0.1 * p.command_mm[0] + back + wobble,
                -0.1 * p.command_mm[1],
            ];
            b.record(
                &plan,
                k,
                Sample {
                    error_um: e,
                    yaw_urad: 0.0,
                },
            )
            .unwrap();
        }
        let id = Identity {
            machine: "m".into(),
            controller: "c".into(),
            board: "b".into(),
            certificate_sha256: String::new(),
            camera: "cam".into(),
        };
        let map = b
            .finish(&plan, id, 1, "t".into(), [0.0; 2], [5.0; 2], [0.0; 2])
            .expect("complete");
        map.check().unwrap();
        let n = map.grid.nodes[0];
        assert!((n.forward.ex_um.mean - 0.0).abs() < 1e-12);
        assert!((n.reverse.ex_um.mean - 6.0).abs() < 1e-12);
        assert!((n.forward.ex_um.sd - 0.4f64 / 2f64.sqrt()).abs() < 1e-12);
        assert!((map.uncertainty_um - 2.0 * (0.08f64 / 2.0).sqrt()).abs() < 1e-9);
        let model = MapModel::new(map);
        let e = model
            .camera_error_um([7.3, 4.1], Direction::REVERSE)
            .unwrap();
        assert!((e[0] - (0.73 + 6.0)).abs() < 1e-9 && (e[1] + 0.41).abs() < 1e-9);
        assert!(b
            .record(
                &plan,
                plan.points.len(),
                Sample {
                    error_um: [0.0; 2],
                    yaw_urad: 0.0
                }
            )
            .is_err());
    }
}
