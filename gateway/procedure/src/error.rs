//! What goes wrong in a procedure's helpers, by kind, so a caller can match on it (the
//! command line prints the message; the service answers a refused input differently from
//! a device that failed). Every message names the file, field or device and where.

/// A procedure's error. The message is complete on its own (it names the file and the
/// line, the record's field, or the device), so fronts print it as it is.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Error {
    /// A file or text from outside that cannot be read or is not what it should be.
    #[error("{0}")]
    Input(String),
    /// A map, reference record or set of constants that belongs to another machine,
    /// set-up or reference than the one it is applied to.
    #[error("{0}")]
    Mismatch(String),
    /// Refused before anything moved or was written: a bound passed, a correction too
    /// large, something the controller would not run as written.
    #[error("{0}")]
    Refused(String),
    /// A device (stage, camera, controller) could not be opened or failed.
    #[error("{0}")]
    Device(String),
    /// An output (an artifact, a frame's thumbnail, a kept file) could not be made or
    /// written.
    #[error("{0}")]
    Output(String),
}

impl Error {
    /// An input error of `what` (a file, a record) with the reason.
    pub fn input(what: impl std::fmt::Display, reason: impl std::fmt::Display) -> Self {
        Error::Input(format!("{what}: {reason}"))
    }
}

/// A bounded reader's refusal (it names the file and its kind).
impl From<std::io::Error> for Error {
    fn from(e: std::io::Error) -> Self {
        Error::Input(e.to_string())
    }
}

/// Where a procedure ends with the message (an [`crate::Outcome`]'s error).
impl From<Error> for String {
    fn from(e: Error) -> Self {
        e.to_string()
    }
}
