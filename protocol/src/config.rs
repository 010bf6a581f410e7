//! Loading TOML data files with errors that name the file, the line and the key.
//!
//! Every configuration and data file of the project (boards, cameras, machines, gateway
//! jobs, drive profiles) goes through [`ConfigDoc`], so a user who mistypes a value is
//! told exactly where, whichever file it was.

use serde::de::DeserializeOwned;
use std::fmt;
use std::path::{Path, PathBuf};

/// Largest data file the loader reads (16 MiB): the largest file the project ships, a
/// board certificate of 135 000 points, is under 4 MiB; anything larger is the wrong file
/// (or a device such as `/dev/zero`, refused before reading because it is not a regular
/// file).
pub const MAX_FILE_BYTES: u64 = 16 * 1024 * 1024;

/// A configuration problem, located as precisely as the file allows.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    // The cause is part of the message (not a `source`), so it prints once however the
    // error is displayed.
    #[error("{file}: cannot read: {cause}")]
    Io {
        file: PathBuf,
        cause: std::io::Error,
    },
    #[error("{location}: {message}")]
    Invalid { location: Location, message: String },
}

/// Where in which file: `file:line:column: key `a.b``.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Location {
    pub file: String,
    pub line: Option<usize>,
    pub column: Option<usize>,
    pub key: Option<String>,
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file)?;
        if let Some(l) = self.line {
            write!(f, ":{l}")?;
            if let Some(c) = self.column {
                write!(f, ":{c}")?;
            }
        }
        if let Some(k) = &self.key {
            write!(f, ": key `{k}`")?;
        }
        Ok(())
    }
}

impl ConfigError {
    pub fn location(&self) -> Option<&Location> {
        match self {
            ConfigError::Io { .. } => None,
            ConfigError::Invalid { location, .. } => Some(location),
        }
    }
}

/// An (x, y) pair in mm read from a two-element array. Serde's fixed-size arrays stop
/// reading after two elements and the TOML reader does not complain about the rest, so
/// `[x, y, z]` read as `[f64; 2]` silently loses its third value: this reads the whole
/// list and insists on two.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Xy(pub [f64; 2]);

/// [`Xy`] for a plain `[f64; 2]` field: `#[serde(deserialize_with = "protocol::config::two_numbers")]`.
pub fn two_numbers<'de, D: serde::Deserializer<'de>>(d: D) -> Result<[f64; 2], D::Error> {
    <Xy as serde::Deserialize>::deserialize(d).map(|Xy(xy)| xy)
}

/// [`two_numbers`] for an optional field (`#[serde(default, deserialize_with = ..)]`).
pub fn optional_two_numbers<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> Result<Option<[f64; 2]>, D::Error> {
    two_numbers(d).map(Some)
}

/// Two diameters (`[0 dot, 1 dot]` of a coded board), the whole list read as [`Xy`].
pub fn two_diameters<'de, D: serde::Deserializer<'de>>(d: D) -> Result<[f64; 2], D::Error> {
    exactly_two(d, "two numbers, [0 dot, 1 dot] diameters in mm")
}

fn exactly_two<'de, D: serde::Deserializer<'de>>(
    d: D,
    what: &'static str,
) -> Result<[f64; 2], D::Error> {
    let v = <Vec<f64> as serde::Deserialize>::deserialize(d)?;
    <[f64; 2]>::try_from(v.as_slice()).map_err(|_| serde::de::Error::invalid_length(v.len(), &what))
}

impl<'de> serde::Deserialize<'de> for Xy {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        exactly_two(d, "two numbers, [x, y] in mm").map(Xy)
    }
}

/// A TOML document with the name it came from, kept so that checks made after parsing
/// (a negative pitch, an unknown driver) can still point at the line of the key.
#[derive(Debug, Clone)]
pub struct ConfigDoc {
    pub name: String,
    pub text: String,
    /// Folder that relative paths inside the document are resolved against.
    pub dir: PathBuf,
    /// Files compiled into the binary (path relative to the repository, text), looked up
    /// before the disk so that embedded defaults can refer to each other.
    pub embedded: &'static [(&'static str, &'static str)],
}

impl ConfigDoc {
    pub fn read(path: &Path) -> Result<Self, ConfigError> {
        let text = read_data_file(path).map_err(|cause| ConfigError::Io {
            file: path.to_path_buf(),
            cause,
        })?;
        Ok(Self {
            name: path.display().to_string(),
            text,
            dir: path.parent().map(Path::to_path_buf).unwrap_or_default(),
            embedded: &[],
        })
    }

    /// A document that did not come from a file (embedded defaults, tests).
    pub fn from_text(name: &str, text: &str, dir: &Path) -> Self {
        Self {
            name: name.to_string(),
            text: text.to_string(),
            dir: dir.to_path_buf(),
            embedded: &[],
        }
    }

    /// An embedded document: `name` is its repository path (e.g.
    /// `config/gateway/demo.toml`); relative references resolve inside `files` first.
    pub fn embedded(name: &str, files: &'static [(&'static str, &'static str)]) -> Option<Self> {
        let text = files.iter().find(|(n, _)| *n == name)?.1;
        let path = Path::new(name);
        Some(Self {
            name: format!("{name} (built in)"),
            text: text.to_string(),
            dir: path.parent().map(Path::to_path_buf).unwrap_or_default(),
            embedded: files,
        })
    }

    /// Read a file named inside this document (relative to it): embedded files first,
    /// then the disk. The error names the document and the key that referred to it.
    pub fn read_relative(&self, key: &str, rel: &str) -> Result<ConfigDoc, ConfigError> {
        let path = normalize(&self.resolve(rel));
        let as_str = path.to_string_lossy().replace('\\', "/");
        if let Some((n, text)) = self.embedded.iter().find(|(n, _)| *n == as_str) {
            return Ok(ConfigDoc {
                name: format!("{n} (built in)"),
                text: text.to_string(),
                dir: path.parent().map(Path::to_path_buf).unwrap_or_default(),
                embedded: self.embedded,
            });
        }
        match read_data_file(&path) {
            Ok(text) => Ok(ConfigDoc {
                name: path.display().to_string(),
                text,
                dir: path.parent().map(Path::to_path_buf).unwrap_or_default(),
                embedded: self.embedded,
            }),
            Err(e) => Err(self.invalid(key, format!("cannot read `{}`: {e}", path.display()))),
        }
    }

    /// Deserialize the whole document; the error names line, column and key path.
    pub fn parse<T: DeserializeOwned>(&self) -> Result<T, ConfigError> {
        let de = toml::de::Deserializer::new(&self.text);
        serde_path_to_error::deserialize(de).map_err(|e| {
            let key = e.path().to_string();
            let inner = e.into_inner();
            let (line, column) = match inner.span() {
                Some(span) => {
                    let (l, c) = line_col(&self.text, span.start);
                    (Some(l), Some(c))
                }
                None => (None, None),
            };
            let key = if key.is_empty() || key == "." {
                None
            } else {
                Some(key)
            };
            let line = line.or_else(|| key.as_deref().and_then(|k| find_key_line(&self.text, k)));
            ConfigError::Invalid {
                location: Location {
                    file: self.name.clone(),
                    line,
                    column,
                    key,
                },
                message: inner.message().trim().to_string(),
            }
        })
    }

    /// An error about `key` (dotted path, e.g. `board.pitch_mm`) found after parsing.
    pub fn invalid(&self, key: &str, message: impl Into<String>) -> ConfigError {
        ConfigError::Invalid {
            location: Location {
                file: self.name.clone(),
                line: find_key_line(&self.text, key),
                column: None,
                key: Some(key.to_string()),
            },
            message: message.into(),
        }
    }

    /// Check a number read from `key` against `lo..=hi` (in `unit`, may be empty): a
    /// non-finite value (TOML's `nan`, `inf`) or one outside the range is refused with a
    /// message naming the range.
    pub fn in_range(
        &self,
        key: &str,
        value: f64,
        lo: f64,
        hi: f64,
        unit: &str,
    ) -> Result<f64, ConfigError> {
        self.check_range(key, value, lo, hi, unit, false)
    }

    /// [`ConfigDoc::in_range`] for a quantity that must be more than zero: `0..=hi`,
    /// zero excluded.
    pub fn positive(&self, key: &str, value: f64, hi: f64, unit: &str) -> Result<f64, ConfigError> {
        self.check_range(key, value, 0.0, hi, unit, true)
    }

    fn check_range(
        &self,
        key: &str,
        value: f64,
        lo: f64,
        hi: f64,
        unit: &str,
        zero_excluded: bool,
    ) -> Result<f64, ConfigError> {
        let with_unit = |v: f64| {
            if unit.is_empty() {
                number(v)
            } else {
                format!("{} {unit}", number(v))
            }
        };
        let range = format!(
            "{}..={}{}",
            number(lo),
            with_unit(hi),
            if zero_excluded { " (0 excluded)" } else { "" }
        );
        if !value.is_finite() {
            return Err(self.invalid(
                key,
                format!("`{value}` is not a finite number: allowed {range}"),
            ));
        }
        if value < lo || value > hi || (zero_excluded && value <= 0.0) {
            return Err(self.invalid(
                key,
                format!("{} is outside the allowed range {range}", with_unit(value)),
            ));
        }
        Ok(value)
    }

    /// Resolve a path written inside the document relative to the document's folder.
    pub fn resolve(&self, rel: &str) -> PathBuf {
        let p = Path::new(rel);
        if p.is_absolute() {
            p.to_path_buf()
        } else {
            self.dir.join(p)
        }
    }
}

/// A number as a reader writes it: `20`, `0.5`, `1e-5`, `1e300` (never 300 digits).
fn number(v: f64) -> String {
    let a = v.abs();
    if a != 0.0 && !(1e-3..1e6).contains(&a) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

/// Write an output file atomically: the bytes go to a new file beside `path` (in the
/// folder that holds the name `path`, created, never opened over anything), are synced,
/// then renamed onto `path`, so a reader sees the old file or the whole new one, never a
/// part. A symbolic link at `path` is replaced by the file, never written through: the
/// file it pointed to is left as it was.
///
/// Refused (nothing written) when `path` names, directly or through any link, a file of
/// `inputs` or any file this process has read through the bounded readers of this
/// module (board, certificate, job, map, its reference record, program: [`was_read`]),
/// so an output never replaces what the run reads, whatever the command forgot to list.
pub fn write_output(path: &Path, bytes: &[u8], inputs: &[&Path]) -> std::io::Result<()> {
    write_output_with(path, inputs, |w| w.write_all(bytes))
}

/// [`write_output`] streamed: `write` writes the file's bytes (buffered) into the new
/// file beside `path`, so an output never needs to be whole in memory; checked before
/// anything is written, synced and renamed as [`write_output`] does. An error from
/// `write` leaves nothing behind (the temporary file is removed, `path` untouched).
pub fn write_output_with(
    path: &Path,
    inputs: &[&Path],
    write: impl FnOnce(&mut dyn std::io::Write) -> std::io::Result<()>,
) -> std::io::Result<()> {
    check_output(path, inputs)?;
    write_beside(path, write)
}

/// [`write_output`] for an output that replaces its own previous version, which the run
/// read first (a map's reference record, a scan journal): the regular file at `path`
/// itself may be replaced; a link there to a file the run read, and `inputs`, are still
/// refused. (The rename replaces the name only, so another name of the same file keeps
/// its content.)
pub fn replace_output(path: &Path, bytes: &[u8], inputs: &[&Path]) -> std::io::Result<()> {
    check(path, inputs, true)?;
    write_beside(path, |w| w.write_all(bytes))
}

/// What [`write_output`] checks before it writes: a command with several outputs checks
/// them all first, so a refused run leaves nothing behind.
pub fn check_output(path: &Path, inputs: &[&Path]) -> std::io::Result<()> {
    check(path, inputs, false)
}

fn check(path: &Path, inputs: &[&Path], replacing: bool) -> std::io::Result<()> {
    use std::io::{Error, ErrorKind};
    if path.file_name().is_none() {
        return Err(Error::new(
            ErrorKind::InvalidInput,
            "the output names no file",
        ));
    }
    // The file the name leads to now (through links), if any.
    let Some(target) = std::fs::metadata(path).ok().and_then(|m| file_id(&m)) else {
        return Ok(());
    };
    for input in inputs {
        if std::fs::metadata(input).ok().and_then(|m| file_id(&m)) == Some(target) {
            return Err(Error::new(
                ErrorKind::AlreadyExists,
                format!(
                    "is {} (an input of this command); it is never written over",
                    input.display()
                ),
            ));
        }
    }
    let is_link = std::fs::symlink_metadata(path).is_ok_and(|m| m.file_type().is_symlink());
    if (is_link || !replacing) && read_before(target) {
        let how = if is_link { "links to" } else { "is" };
        return Err(Error::new(
            ErrorKind::AlreadyExists,
            format!("{how} a file this run read; it is never written over"),
        ));
    }
    Ok(())
}

fn write_beside(
    path: &Path,
    write: impl FnOnce(&mut dyn std::io::Write) -> std::io::Result<()>,
) -> std::io::Result<()> {
    use std::io::{Error, ErrorKind, Write};
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let name = path
        .file_name()
        .ok_or_else(|| Error::new(ErrorKind::InvalidInput, "the output names no file"))?;
    let stamp = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos())
        .unwrap_or(0);
    let tmp = dir.join(format!(
        ".{}.{}.{stamp}.tmp",
        name.to_string_lossy(),
        std::process::id()
    ));
    let written = (|| {
        let f = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&tmp)?;
        let mut buffered = std::io::BufWriter::with_capacity(1 << 16, f);
        write(&mut buffered)?;
        buffered.flush()?;
        let f = buffered.into_inner().map_err(|e| e.into_error())?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)?;
        // The rename made durable too (the folder's entry), where the folder opens.
        if let Ok(d) = std::fs::File::open(dir) {
            let _ = d.sync_all();
        }
        Ok(())
    })();
    if written.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    written
}

/// A file's identity: device, inode and modification time, the same for every name and
/// link of it. The time tells a file from a later one given the inode of a deleted one.
type FileId = (u64, u64, i64, i64);

#[cfg(unix)]
fn file_id(meta: &std::fs::Metadata) -> Option<FileId> {
    use std::os::unix::fs::MetadataExt;
    Some((meta.dev(), meta.ino(), meta.mtime(), meta.mtime_nsec()))
}

#[cfg(not(unix))]
fn file_id(_: &std::fs::Metadata) -> Option<FileId> {
    None
}

/// The most files [`was_read`] remembers (32 bytes each): a command reads a few
/// dozen; a service that reads more stops adding (documented in docs/reliability.md).
const MAX_FILES_READ: usize = 1 << 16;

static FILES_READ: std::sync::Mutex<Vec<FileId>> = std::sync::Mutex::new(Vec::new());

/// Whether this process has read the file `path` names (through any link or name)
/// through the bounded readers of this module: [`write_output`] never replaces one.
pub fn was_read(path: &Path) -> bool {
    std::fs::metadata(path)
        .ok()
        .and_then(|m| file_id(&m))
        .is_some_and(read_before)
}

fn read_before(id: FileId) -> bool {
    FILES_READ
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .contains(&id)
}

fn note_read(meta: &std::fs::Metadata) {
    let Some(id) = file_id(meta) else { return };
    let mut read = FILES_READ.lock().unwrap_or_else(|e| e.into_inner());
    if !read.contains(&id) && read.len() < MAX_FILES_READ {
        read.push(id);
    }
}

/// Read a data file as text, bounded: only a regular file (a device such as `/dev/zero`,
/// a FIFO or a directory is refused before anything is read) of at most
/// [`MAX_FILE_BYTES`], in UTF-8; a leading byte-order mark is dropped. Every file the
/// loader reads goes through here.
pub fn read_data_file(path: &Path) -> std::io::Result<String> {
    read_bounded(path, MAX_FILE_BYTES, "a data file")
}

/// The kinds of file read from outside, each with the most bytes it may have: a file
/// larger than its kind's cap is the wrong file, refused before it is read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DataKind {
    /// A G-code program (read as a stream of lines, [`open_lines`]).
    Program,
    /// A layout (JSON, SVG, DXF).
    Layout,
    /// A rotary centres file (CSV).
    Centres,
    /// A rotary errors file (JSON) or machine constants (JSON).
    RotaryJson,
    /// A volumetric model or campaign (CSV).
    Volumetric,
    /// An ISO 230-2 measurements file (CSV).
    Iso230,
    /// A controller's saved `$#` reply.
    Parameters,
    /// A configuration file (TOML, JSON job): jobs, boards, cameras, machines.
    Config,
    /// An error map (JSON).
    ErrorMap,
}

impl DataKind {
    /// The most bytes a file of this kind may have.
    pub fn max_bytes(self) -> u64 {
        match self {
            DataKind::Program => 64 << 20,
            DataKind::Layout => MAX_FILE_BYTES,
            DataKind::Centres => 4 << 20,
            DataKind::RotaryJson => 4 << 20,
            DataKind::Volumetric => MAX_FILE_BYTES,
            DataKind::Iso230 => 8 << 20,
            DataKind::Parameters => 1 << 20,
            DataKind::Config => MAX_FILE_BYTES,
            // A dense 200 x 200 grid with lines is under 10 MB.
            DataKind::ErrorMap => 64 << 20,
        }
    }

    /// How messages name a file of this kind.
    pub fn name(self) -> &'static str {
        match self {
            DataKind::Program => "program",
            DataKind::Layout => "layout",
            DataKind::Centres => "centres file",
            DataKind::RotaryJson => "rotary errors or machine file",
            DataKind::Volumetric => "volumetric file",
            DataKind::Iso230 => "measurements file (ISO 230-2)",
            DataKind::Parameters => "`$#` reply",
            DataKind::Config => "configuration file",
            DataKind::ErrorMap => "error map",
        }
    }
}

/// [`read_data_file`] for a file of `kind`: its kind's size cap, and an error that
/// names the file and its kind (`layout /tmp/x.svg: not a regular file (a FIFO)...`), so
/// a caller need not add them.
pub fn read_kind(path: &Path, kind: DataKind) -> std::io::Result<String> {
    read_bounded(path, kind.max_bytes(), &format!("a {}", kind.name()))
        .map_err(|e| name_file(path, kind, e))
}

fn name_file(path: &Path, kind: DataKind, e: std::io::Error) -> std::io::Error {
    std::io::Error::new(e.kind(), format!("{} {}: {e}", kind.name(), path.display()))
}

/// The most bytes one line of a program may have in [`open_lines`]: GRBL's line buffer
/// holds 80, a CAM system's comment lines are longer, nothing real is near 64 KiB.
pub const MAX_LINE_BYTES: usize = 64 << 10;

/// A file read as a stream of lines: regular files only (refused before opening, as
/// [`read_kind`] does), at most `kind`'s size cap in all and [`MAX_LINE_BYTES`] per
/// line, UTF-8. Each item is `(line number from 1, the line without its ending)`; an
/// error names the file and the line. Memory is one line, whatever the file's size.
pub fn open_lines(path: &Path, kind: DataKind) -> std::io::Result<Lines> {
    let file = open_regular(path).map_err(|e| name_file(path, kind, e))?;
    let len = file.metadata().map_err(|e| name_file(path, kind, e))?.len();
    if len > kind.max_bytes() {
        let what = format!("a {}", kind.name());
        return Err(name_file(path, kind, too_big(len, kind.max_bytes(), &what)));
    }
    Ok(Lines {
        reader: std::io::BufReader::new(file),
        path: path.to_path_buf(),
        kind,
        line: 0,
        read: 0,
        done: false,
        keep_endings: false,
    })
}

/// The lines of a file opened with [`open_lines`].
pub struct Lines {
    reader: std::io::BufReader<std::fs::File>,
    path: PathBuf,
    kind: DataKind,
    line: usize,
    read: u64,
    done: bool,
    keep_endings: bool,
}

impl Lines {
    /// Lines with their endings (`\n`, `\r\n`, none for a last line without one), so
    /// that joining them gives the file's text back.
    pub fn keep_endings(mut self) -> Self {
        self.keep_endings = true;
        self
    }
}

impl Iterator for Lines {
    type Item = std::io::Result<(usize, String)>;

    fn next(&mut self) -> Option<Self::Item> {
        use std::io::{BufRead, Error, ErrorKind};
        if self.done {
            return None;
        }
        self.line += 1;
        let mut buf = Vec::new();
        let fail = |this: &mut Self, message: String| {
            this.done = true;
            Some(Err(Error::new(
                ErrorKind::InvalidData,
                format!(
                    "{} {}: line {}: {message}",
                    this.kind.name(),
                    this.path.display(),
                    this.line
                ),
            )))
        };
        loop {
            let chunk = match self.reader.fill_buf() {
                Ok(c) => c,
                Err(e) if e.kind() == ErrorKind::Interrupted => continue,
                Err(e) => return fail(self, e.to_string()),
            };
            if chunk.is_empty() {
                break;
            }
            let (take, end) = match chunk.iter().position(|&b| b == b'\n') {
                Some(p) => (p + 1, true),
                None => (chunk.len(), false),
            };
            buf.extend_from_slice(&chunk[..take]);
            self.reader.consume(take);
            self.read += take as u64;
            if self.read > self.kind.max_bytes() {
                let cap = self.kind.max_bytes();
                return fail(
                    self,
                    format!("the file grew past {} MiB while being read", cap >> 20),
                );
            }
            if buf.len() > MAX_LINE_BYTES + 2 {
                return fail(
                    self,
                    format!(
                        "longer than the {} KiB a line may have",
                        MAX_LINE_BYTES >> 10
                    ),
                );
            }
            if end {
                break;
            }
        }
        if buf.is_empty() {
            self.done = true;
            return None;
        }
        let mut ending: &[u8] = b"";
        if buf.ends_with(b"\r\n") {
            ending = b"\r\n";
        } else if buf.ends_with(b"\n") {
            ending = b"\n";
        }
        buf.truncate(buf.len() - ending.len());
        if buf.len() > MAX_LINE_BYTES {
            return fail(
                self,
                format!(
                    "longer than the {} KiB a line may have",
                    MAX_LINE_BYTES >> 10
                ),
            );
        }
        match String::from_utf8(buf) {
            Ok(mut s) => {
                if self.line == 1 && s.starts_with('\u{FEFF}') {
                    s.drain(..3);
                }
                if self.keep_endings {
                    s.push_str(if ending == b"\r\n" {
                        "\r\n"
                    } else if ending.is_empty() {
                        ""
                    } else {
                        "\n"
                    });
                }
                Some(Ok((self.line, s)))
            }
            Err(e) => {
                let at = e.utf8_error().valid_up_to();
                fail(self, format!("not UTF-8 text (column {})", at + 1))
            }
        }
    }
}

fn too_big(size: u64, cap: u64, what: &str) -> std::io::Error {
    let cap_text = if cap >= 1 << 20 {
        format!("{} MiB", cap >> 20)
    } else {
        format!("{} KiB", cap >> 10)
    };
    std::io::Error::new(
        std::io::ErrorKind::InvalidData,
        format!("the file has {size} bytes, more than the {cap_text} {what} may have"),
    )
}

/// Opens a regular file for reading, refusing anything else before opening it (opening
/// a FIFO would block until a writer comes), and again on the opened file (the path may
/// have been swapped in between).
fn open_regular(path: &Path) -> std::io::Result<std::fs::File> {
    check_regular(&std::fs::metadata(path)?)?;
    let file = std::fs::File::open(path)?;
    let meta = file.metadata()?;
    check_regular(&meta)?;
    note_read(&meta);
    Ok(file)
}

/// A regular file of at most `cap` bytes (refused before opening otherwise, see
/// [`open_regular`]); `what` names the kind in the size message. For files that are
/// not text (journals with their checksums); text goes through [`read_kind`].
pub fn read_bytes_bounded(path: &Path, cap: u64, what: &str) -> std::io::Result<Vec<u8>> {
    use std::io::Read;
    let file = open_regular(path)?;
    let meta = file.metadata()?;
    if meta.len() > cap {
        return Err(too_big(meta.len(), cap, what));
    }
    let mut bytes = Vec::with_capacity(meta.len() as usize);
    file.take(cap + 1).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > cap {
        // It grew while being read (or its size was not known).
        return Err(too_big(bytes.len() as u64, cap, what));
    }
    Ok(bytes)
}

/// A regular file of at most `cap` bytes as UTF-8 text (a leading byte-order mark
/// dropped); `what` names the kind in the size message.
fn read_bounded(path: &Path, cap: u64, what: &str) -> std::io::Result<String> {
    use std::io::{Error, ErrorKind};
    let bytes = read_bytes_bounded(path, cap, what)?;
    let text = String::from_utf8(bytes).map_err(|e| {
        let at = e.utf8_error().valid_up_to();
        let line = e.as_bytes()[..at].iter().filter(|&&b| b == b'\n').count() + 1;
        Error::new(
            ErrorKind::InvalidData,
            format!("not UTF-8 text (line {line}, byte {at})"),
        )
    })?;
    Ok(match text.strip_prefix('\u{FEFF}') {
        Some(rest) => rest.to_string(),
        None => text,
    })
}

fn check_regular(meta: &std::fs::Metadata) -> std::io::Result<()> {
    let t = meta.file_type();
    if t.is_file() {
        return Ok(());
    }
    let kind = if t.is_dir() {
        "a directory"
    } else {
        special_kind(&t)
    };
    Err(std::io::Error::new(
        std::io::ErrorKind::InvalidInput,
        format!("not a regular file ({kind}); a data file must be a regular file"),
    ))
}

#[cfg(unix)]
fn special_kind(t: &std::fs::FileType) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    if t.is_char_device() {
        "a character device"
    } else if t.is_block_device() {
        "a block device"
    } else if t.is_fifo() {
        "a FIFO"
    } else if t.is_socket() {
        "a socket"
    } else {
        "a special file"
    }
}

#[cfg(not(unix))]
fn special_kind(_: &std::fs::FileType) -> &'static str {
    "a special file"
}

/// Lexical normalisation (`a/b/../c` -> `a/c`), so embedded names match.
fn normalize(p: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for c in p.components() {
        match c {
            std::path::Component::ParentDir => {
                if !out.pop() {
                    out.push("..");
                }
            }
            std::path::Component::CurDir => {}
            other => out.push(other),
        }
    }
    out
}

fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let before = &text[..offset.min(text.len())];
    let line = before.matches('\n').count() + 1;
    let col = before
        .rfind('\n')
        .map_or(before.len(), |i| before.len() - i - 1)
        + 1;
    (line, col)
}

/// Line of a key path as serde names it (`stage.axes[1].node`, `targets[3].x_mm`,
/// `board.origin_mm[1]`): the line of the key itself, or of the array element for an
/// index, found in the parsed document's spans, so keys inside inline tables and elements
/// of inline arrays written over several lines are found. A document that does not parse
/// falls back to a line scan of `[table]` headers and `key =` lines.
pub fn find_key_line(text: &str, dotted: &str) -> Option<usize> {
    match key_span(text, dotted) {
        Some(offset) => Some(line_col(text, offset).0),
        None => scan_key_line(text, dotted),
    }
}

/// One step of a key path.
#[derive(Debug, PartialEq)]
enum Step<'a> {
    Key(&'a str),
    Index(usize),
}

/// `a.b[1].c` -> `a`, `b`, `[1]`, `c`; None for anything else (serde's `?`).
fn key_path(dotted: &str) -> Option<Vec<Step<'_>>> {
    let mut steps = Vec::new();
    for part in dotted.split('.') {
        let (name, mut rest) = part.split_at(part.find('[').unwrap_or(part.len()));
        if !name.is_empty() {
            steps.push(Step::Key(name.trim_matches('"')));
        } else if steps.is_empty() || !rest.starts_with('[') {
            return None;
        }
        while let Some(r) = rest.strip_prefix('[') {
            let (n, after) = r.split_once(']')?;
            steps.push(Step::Index(n.parse().ok()?));
            rest = after;
        }
        if !rest.is_empty() {
            return None;
        }
    }
    Some(steps)
}

/// Byte offset of the last step of `dotted` in `text` (its key, or its array element).
fn key_span(text: &str, dotted: &str) -> Option<usize> {
    use toml_edit::{Item, TableLike, Value};
    enum Node<'a> {
        Item(&'a Item),
        Value(&'a Value),
        Table(&'a toml_edit::Table),
    }
    let doc = toml_edit::ImDocument::parse(text).ok()?;
    let mut node = Node::Table(doc.as_table());
    let mut at = None;
    for step in key_path(dotted)? {
        let (next, span) = match step {
            Step::Key(k) => {
                let table: &dyn TableLike = match node {
                    Node::Table(t) => t,
                    Node::Item(i) => i.as_table_like()?,
                    Node::Value(Value::InlineTable(t)) => t,
                    Node::Value(_) => return None,
                };
                let (key, item) = table.get_key_value(k)?;
                (Node::Item(item), key.span().or_else(|| item.span()))
            }
            Step::Index(n) => match node {
                Node::Item(Item::ArrayOfTables(a)) => {
                    let t = a.get(n)?;
                    (Node::Table(t), t.span())
                }
                Node::Item(Item::Value(Value::Array(a))) | Node::Value(Value::Array(a)) => {
                    let v = a.get(n)?;
                    (Node::Value(v), v.span())
                }
                _ => return None,
            },
        };
        node = next;
        at = span.map(|s| s.start).or(at);
    }
    at
}

/// Best-effort line of a dotted key: tracks `[table]` headers and matches `key =` lines.
/// Array-of-table indices (`targets[3]`) are matched by counting `[[targets]]` headers.
fn scan_key_line(text: &str, dotted: &str) -> Option<usize> {
    let parts: Vec<String> = dotted.split('.').map(str::to_string).collect();
    let mut table: Vec<String> = Vec::new();
    let mut array_counts: std::collections::HashMap<String, usize> = Default::default();
    let mut header_match: Option<usize> = None;
    for (n, raw) in text.lines().enumerate() {
        let line = raw.trim();
        if line.starts_with("[[") {
            let name = line
                .trim_start_matches("[[")
                .split("]]")
                .next()
                .unwrap_or("")
                .trim();
            let c = array_counts.entry(name.to_string()).or_insert(0);
            table = name.split('.').map(|s| s.trim().to_string()).collect();
            if let Some(last) = table.last_mut() {
                *last = format!("{last}[{c}]");
            }
            *c += 1;
        } else if line.starts_with('[') {
            let name = line
                .trim_start_matches('[')
                .split(']')
                .next()
                .unwrap_or("")
                .trim();
            table = name.split('.').map(|s| s.trim().to_string()).collect();
        } else if let Some((k, _)) = line.split_once('=') {
            let mut full = table.clone();
            full.extend(
                k.trim()
                    .trim_matches('"')
                    .split('.')
                    .map(|s| s.trim().to_string()),
            );
            if full == parts {
                return Some(n + 1);
            }
            continue;
        } else {
            continue;
        }
        if table == parts && header_match.is_none() {
            header_match = Some(n + 1);
        }
    }
    header_match
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(serde::Deserialize, Debug)]
    #[serde(deny_unknown_fields)]
    #[allow(dead_code)]
    struct Doc {
        stage: Stage,
    }
    #[derive(serde::Deserialize, Debug)]
    #[serde(deny_unknown_fields)]
    #[allow(dead_code)]
    struct Stage {
        travel_mm: f64,
        name: String,
    }

    fn doc(text: &str) -> ConfigDoc {
        ConfigDoc::from_text("machine.toml", text, Path::new("."))
    }

    #[test]
    fn wrong_type_names_file_line_and_key() {
        let err = doc("[stage]\nname = \"a\"\ntravel_mm = \"long\"\n")
            .parse::<Doc>()
            .unwrap_err();
        let loc = err.location().unwrap();
        assert_eq!(loc.file, "machine.toml");
        assert_eq!(loc.line, Some(3));
        assert_eq!(loc.key.as_deref(), Some("stage.travel_mm"));
        assert!(err.to_string().starts_with("machine.toml:3:"), "{err}");
    }

    #[test]
    fn unknown_and_missing_keys_are_reported() {
        let err = doc("[stage]\nname = \"a\"\ntravel_mm = 1.0\nspeed = 3\n")
            .parse::<Doc>()
            .unwrap_err();
        assert!(err.to_string().contains("speed"), "{err}");
        let err = doc("[stage]\nname = \"a\"\n").parse::<Doc>().unwrap_err();
        assert!(err.to_string().contains("travel_mm"), "{err}");
    }

    #[test]
    fn syntax_error_has_a_line() {
        let err = doc("[stage]\nname = \"a\ntravel_mm = 1\n")
            .parse::<Doc>()
            .unwrap_err();
        assert_eq!(err.location().unwrap().line, Some(2), "{err}");
    }

    #[test]
    fn invalid_after_parse_finds_the_key_line() {
        let d = doc("# c\n[stage]\nname = \"a\"\ntravel_mm = -1.0\n");
        let err = d.invalid("stage.travel_mm", "must be positive");
        assert_eq!(err.location().unwrap().line, Some(4));
        assert_eq!(
            err.to_string(),
            "machine.toml:4: key `stage.travel_mm`: must be positive"
        );
    }

    #[test]
    fn embedded_documents_resolve_each_other_first() {
        static FILES: &[(&str, &str)] = &[
            (
                "config/gateway/demo.toml",
                "[stage]\nmachine = \"../machines/m.toml\"\n",
            ),
            ("config/machines/m.toml", "x = 1\n"),
        ];
        let d = ConfigDoc::embedded("config/gateway/demo.toml", FILES).unwrap();
        let m = d
            .read_relative("stage.machine", "../machines/m.toml")
            .unwrap();
        assert_eq!(m.text, "x = 1\n");
        let e = d
            .read_relative("stage.machine", "../machines/nope.toml")
            .unwrap_err();
        assert!(
            e.to_string()
                .contains("demo.toml (built in):2: key `stage.machine`"),
            "{e}"
        );
    }

    #[test]
    fn ranges_refuse_non_finite_and_outside_values_naming_the_range() {
        let d = doc("[c]\nblur = 1e5\nn = nan\n");
        assert_eq!(d.in_range("c.blur", 2.0, 0.0, 20.0, "px").unwrap(), 2.0);
        let e = d.in_range("c.blur", 1e5, 0.0, 20.0, "px").unwrap_err();
        assert_eq!(
            e.to_string(),
            "machine.toml:2: key `c.blur`: 100000 px is outside the allowed range 0..=20 px"
        );
        let e = d.in_range("c.n", f64::NAN, 0.0, 1.0, "").unwrap_err();
        assert_eq!(
            e.to_string(),
            "machine.toml:3: key `c.n`: `NaN` is not a finite number: allowed 0..=1"
        );
        let e = d.positive("c.blur", 0.0, 1e6, "mm/min").unwrap_err();
        assert!(
            e.to_string()
                .ends_with("0 mm/min is outside the allowed range 0..=1e6 mm/min (0 excluded)"),
            "{e}"
        );
        let e = d.positive("c.blur", 1e300, 1e5, "mm").unwrap_err();
        assert!(e.to_string().contains("1e300 mm is outside"), "{e}");
    }

    #[test]
    fn key_paths_are_split_like_serde_writes_them() {
        use Step::*;
        assert_eq!(
            key_path("stage.axes[1].node"),
            Some(vec![Key("stage"), Key("axes"), Index(1), Key("node")])
        );
        assert_eq!(
            key_path("m[0][2]"),
            Some(vec![Key("m"), Index(0), Index(2)])
        );
        assert_eq!(key_path("a.?"), Some(vec![Key("a"), Key("?")]));
        assert_eq!(key_path("a[x]"), None);
        // A document that does not parse still gets the line scan.
        assert_eq!(find_key_line("[a]\nb = 1\nc = \"\n", "a.b"), Some(2));
    }

    #[test]
    fn array_of_tables_keys_are_found() {
        let text = "[[t]]\nx = 1\n[[t]]\nx = 2\n";
        assert_eq!(find_key_line(text, "t[1].x"), Some(4));
        assert_eq!(find_key_line(text, "t[0].x"), Some(2));
    }
    fn temp_dir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("protocol-config-{name}-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn special_files_are_refused_before_reading() {
        let e = ConfigDoc::read(Path::new("/dev/zero"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("/dev/zero") && e.contains("not a regular file"),
            "{e}"
        );
        let e = doc("[board]\nfile = \"/dev/zero\"\n")
            .read_relative("board.file", "/dev/zero")
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("machine.toml:2: key `board.file`") && e.contains("not a regular file"),
            "{e}"
        );
        let dir = temp_dir("dir");
        let e = ConfigDoc::read(&dir).unwrap_err().to_string();
        assert!(e.contains("a directory"), "{e}");
    }

    /// Every kind refuses a FIFO (without waiting for a writer: the check comes before
    /// the open) and `/dev/zero` (never read), naming the kind and the file; the same
    /// for the line stream.
    #[cfg(unix)]
    #[test]
    fn every_kind_refuses_a_fifo_and_dev_zero_at_once() {
        let dir = temp_dir("fifo");
        let fifo = dir.join("in.fifo");
        let made = std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap();
        assert!(made.success());
        let kinds = [
            DataKind::Program,
            DataKind::Layout,
            DataKind::Centres,
            DataKind::RotaryJson,
            DataKind::Volumetric,
            DataKind::Iso230,
            DataKind::Parameters,
            DataKind::Config,
        ];
        for kind in kinds {
            let e = read_kind(&fifo, kind).unwrap_err().to_string();
            assert!(
                e.starts_with(&format!(
                    "{} {}: not a regular file (a FIFO)",
                    kind.name(),
                    fifo.display()
                )),
                "{e}"
            );
            let e = read_kind(Path::new("/dev/zero"), kind)
                .unwrap_err()
                .to_string();
            assert_eq!(
                e,
                format!("{} /dev/zero: not a regular file (a character device); a data file must be a regular file", kind.name())
            );
            let e = open_lines(&fifo, kind).err().unwrap().to_string();
            assert!(e.contains("not a regular file (a FIFO)"), "{e}");
            let e = open_lines(Path::new("/dev/zero"), kind)
                .err()
                .unwrap()
                .to_string();
            assert!(e.contains("/dev/zero: not a regular file"), "{e}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// Each kind has its cap (a sparse file one byte over it is refused unread, the
    /// message naming the cap, the kind and the file).
    #[test]
    fn each_kind_has_its_size_cap() {
        let dir = temp_dir("caps");
        let big = dir.join("big.csv");
        let f = std::fs::File::create(&big).unwrap();
        f.set_len(DataKind::Centres.max_bytes() + 1).unwrap();
        let e = read_kind(&big, DataKind::Centres).unwrap_err().to_string();
        assert_eq!(
            e,
            format!(
                "centres file {}: the file has 4194305 bytes, more than the 4 MiB a centres file may have",
                big.display()
            )
        );
        assert!(read_kind(&big, DataKind::Layout).is_ok());
        f.set_len(DataKind::Parameters.max_bytes() + 1).unwrap();
        let e = read_kind(&big, DataKind::Parameters)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("more than the 1 MiB a `$#` reply may have"),
            "{e}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A program read as a stream: its lines (any ending, a BOM dropped), a line too
    /// long or not UTF-8 named by its number, memory one line at a time.
    #[test]
    fn programs_are_read_as_a_bounded_stream_of_lines() {
        let dir = temp_dir("lines");
        let p = dir.join("p.nc");
        std::fs::write(&p, "\u{FEFF}G0 X1\r\nG1 Y2 F100\n\nM2").unwrap();
        let lines: Vec<(usize, String)> = open_lines(&p, DataKind::Program)
            .unwrap()
            .collect::<Result<_, _>>()
            .unwrap();
        assert_eq!(
            lines,
            vec![
                (1, "G0 X1".to_string()),
                (2, "G1 Y2 F100".to_string()),
                (3, String::new()),
                (4, "M2".to_string())
            ]
        );
        let text: String = open_lines(&p, DataKind::Program)
            .unwrap()
            .keep_endings()
            .map(|l| l.unwrap().1)
            .collect();
        assert_eq!(text, "G0 X1\r\nG1 Y2 F100\n\nM2");
        let mut long = "G0 X1\n".to_string();
        long.push_str(&"X".repeat(MAX_LINE_BYTES + 1));
        long.push_str("\nG0 X2\n");
        std::fs::write(&p, &long).unwrap();
        let got: Vec<_> = open_lines(&p, DataKind::Program).unwrap().collect();
        assert_eq!(got.len(), 2, "the stream ends at the error");
        let e = got[1].as_ref().unwrap_err().to_string();
        assert_eq!(
            e,
            format!(
                "program {}: line 2: longer than the 64 KiB a line may have",
                p.display()
            )
        );
        std::fs::write(&p, b"G0 X1\nG0 \xff\n").unwrap();
        let got: Vec<_> = open_lines(&p, DataKind::Program).unwrap().collect();
        let e = got[1].as_ref().unwrap_err().to_string();
        assert!(e.ends_with("line 2: not UTF-8 text (column 4)"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn files_larger_than_the_limit_are_refused() {
        let dir = temp_dir("big");
        let big = dir.join("big.csv");
        let f = std::fs::File::create(&big).unwrap();
        f.set_len(MAX_FILE_BYTES + 1).unwrap(); // sparse: nothing is written
        let e = ConfigDoc::read(&big).unwrap_err().to_string();
        assert!(e.contains("16 MiB"), "{e}");
        let ok = dir.join("ok.toml");
        std::fs::write(&ok, "x = 1\n").unwrap();
        assert_eq!(ConfigDoc::read(&ok).unwrap().text, "x = 1\n");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_leading_byte_order_mark_is_dropped() {
        let dir = temp_dir("bom");
        let p = dir.join("bom.toml");
        std::fs::write(&p, "\u{FEFF}[stage]\nname = \"a\"\ntravel_mm = 1.0\n").unwrap();
        let d = ConfigDoc::read(&p).unwrap();
        assert!(d.text.starts_with("[stage]"));
        d.parse::<Doc>().unwrap();
        let r = doc("").read_relative("k", p.to_str().unwrap()).unwrap();
        assert!(r.text.starts_with("[stage]"));
        std::fs::remove_dir_all(&dir).unwrap();
    }
    #[derive(serde::Deserialize, Debug)]
    #[serde(deny_unknown_fields)]
    #[allow(dead_code)]
    struct Axes {
        stage: AxesStage,
    }
    #[derive(serde::Deserialize, Debug)]
    #[serde(deny_unknown_fields)]
    #[allow(dead_code)]
    struct AxesStage {
        name: String,
        axes: Vec<Axis>,
    }
    #[derive(serde::Deserialize, Debug)]
    #[serde(deny_unknown_fields)]
    #[allow(dead_code)]
    struct Axis {
        node: u8,
    }

    #[test]
    fn errors_inside_inline_arrays_name_the_line_of_the_element() {
        let text = "[stage]\nname = \"a\"\naxes = [\n  { node = 1 },\n  { node = \"two\" },\n]\n";
        let err = doc(text).parse::<Axes>().unwrap_err();
        let loc = err.location().unwrap();
        assert_eq!(loc.key.as_deref(), Some("stage.axes[1].node"), "{err}");
        assert_eq!(loc.line, Some(5), "{err}");
        // Checks made after parsing find the element too, and the key inside it.
        let d = doc(text);
        assert_eq!(
            d.invalid("stage.axes[1].node", "m")
                .location()
                .unwrap()
                .line,
            Some(5)
        );
        assert_eq!(
            d.invalid("stage.axes[0]", "m").location().unwrap().line,
            Some(4)
        );
        assert_eq!(
            d.invalid("stage.axes", "m").location().unwrap().line,
            Some(3)
        );
        // An inline array of numbers, one element per line.
        let d = doc("[board]\norigin_mm = [\n  1.0,\n  2.0,\n]\n");
        assert_eq!(
            d.invalid("board.origin_mm[1]", "m")
                .location()
                .unwrap()
                .line,
            Some(4)
        );
        // Inline tables and dotted keys.
        let d = doc("stage = { name = \"a\", axes = [{ node = 1 },\n  { node = 300 }] }\n");
        let err = d.parse::<Axes>().unwrap_err();
        assert_eq!(err.location().unwrap().line, Some(2), "{err}");
        let d = doc("[[t]]\nx = 1\n[[t]]\nx = [1,\n 2]\n");
        assert_eq!(
            d.invalid("t[1].x[1]", "m").location().unwrap().line,
            Some(5)
        );
    }

    #[test]
    fn outputs_are_written_whole_and_never_over_an_input() {
        let dir = std::env::temp_dir().join(format!("write-output-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let input = dir.join("in.nc");
        std::fs::write(&input, "G0 X1\n").unwrap();
        let out = dir.join("out.nc");
        write_output(&out, b"first", &[&input]).unwrap();
        write_output(&out, b"second", &[&input]).unwrap();
        assert_eq!(std::fs::read_to_string(&out).unwrap(), "second");
        // The input itself, by another spelling and through a symlink: refused.
        let again = dir.join(".").join("in.nc");
        let e = write_output(&again, b"x", &[&input]).unwrap_err();
        assert!(e.to_string().contains("never written over"), "{e}");
        #[cfg(unix)]
        {
            let link = dir.join("link.nc");
            std::os::unix::fs::symlink(&input, &link).unwrap();
            assert!(write_output(&link, b"x", &[&input]).is_err());
        }
        assert_eq!(std::fs::read_to_string(&input).unwrap(), "G0 X1\n");
        // No temporary file is left behind.
        let left: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .filter_map(|e| e.ok())
            .filter(|e| e.file_name().to_string_lossy().ends_with(".tmp"))
            .collect();
        assert!(left.is_empty());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// The streaming writer: the bytes go in pieces into the file beside the name;
    /// a writer that fails half-way leaves the old file as it was and nothing beside it.
    #[test]
    fn a_streamed_output_is_written_whole_or_not_at_all() {
        let dir = std::env::temp_dir().join(format!("write-stream-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let out = dir.join("art.svg");
        write_output_with(&out, &[], |w| {
            (0..100_000).try_for_each(|i| writeln!(w, "<circle n=\"{i}\"/>"))
        })
        .unwrap();
        let text = std::fs::read_to_string(&out).unwrap();
        assert_eq!(text.lines().count(), 100_000);
        assert!(text.ends_with("<circle n=\"99999\"/>\n"));
        let e = write_output_with(&out, &[], |w| {
            w.write_all(b"half")?;
            Err(std::io::Error::other("the disk is full"))
        })
        .unwrap_err();
        assert!(e.to_string().contains("disk is full"), "{e}");
        assert_eq!(std::fs::read_to_string(&out).unwrap(), text);
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);
        // An input is refused before `write` runs.
        let mut ran = false;
        assert!(write_output_with(&out, &[&out], |_| {
            ran = true;
            Ok(())
        })
        .is_err());
        assert!(!ran);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// Issue 38: `gateway reference` wrote its record through a link onto the job's
    /// board file; `board make -o` replaced the board's certificate; `rewrite --out
    /// MAP.reference.json` replaced the record it read. Whatever a command lists as its
    /// inputs, a file it read is never replaced, and a link is never written through.
    #[cfg(unix)]
    #[test]
    fn a_file_the_run_read_is_never_replaced_and_links_are_never_written_through() {
        let dir = std::env::temp_dir().join(format!("write-read-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let board = dir.join("board.toml");
        std::fs::write(&board, "name = \"b\"\n").unwrap();
        let record = dir.join("map.reference.json");
        std::fs::write(&record, "{}").unwrap();
        let unread = dir.join("unread.txt");
        std::fs::write(&unread, "kept").unwrap();
        read_data_file(&board).unwrap();
        read_bytes_bounded(&record, 1 << 10, "a record").unwrap();
        assert!(was_read(&board) && was_read(&record) && !was_read(&unread));
        // Not listed as an input, yet read: refused, by its name and through a link.
        let e = write_output(&board, b"x", &[]).unwrap_err();
        assert!(e.to_string().contains("a file this run read"), "{e}");
        let link = dir.join("link.json");
        std::os::unix::fs::symlink(&board, &link).unwrap();
        let e = write_output(&link, b"x", &[]).unwrap_err();
        assert!(
            e.to_string().contains("links to a file this run read"),
            "{e}"
        );
        let e = replace_output(&link, b"x", &[]).unwrap_err();
        assert!(e.to_string().contains("links to"), "{e}");
        assert!(check_output(&link, &[]).is_err());
        // An output replacing its own previous version (read first) may; an input not.
        replace_output(&record, b"{\"new\": 1}", &[]).unwrap();
        assert_eq!(std::fs::read_to_string(&record).unwrap(), "{\"new\": 1}");
        assert!(replace_output(&record, b"x", &[&record]).is_err());
        // A link to a file not read is replaced by the output; its target stays.
        let other = dir.join("other.txt");
        std::os::unix::fs::symlink(&unread, &other).unwrap();
        write_output(&other, b"new", &[]).unwrap();
        assert!(!std::fs::symlink_metadata(&other)
            .unwrap()
            .file_type()
            .is_symlink());
        assert_eq!(std::fs::read_to_string(&other).unwrap(), "new");
        assert_eq!(std::fs::read_to_string(&unread).unwrap(), "kept");
        assert_eq!(std::fs::read_to_string(&board).unwrap(), "name = \"b\"\n");
        let left = std::fs::read_dir(&dir)
            .unwrap()
            .filter_map(|e| e.ok())
            .filter(|e| e.file_name().to_string_lossy().ends_with(".tmp"))
            .count();
        assert_eq!(left, 0);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
