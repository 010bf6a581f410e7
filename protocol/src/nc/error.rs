//! What went wrong and where: every syntax error names the line, the column and the
//! text that could not be read, so a user can find it in an editor.

use std::fmt;

/// A place in a program text: 1-based line, and 1-based column counted in characters
/// (what an editor shows).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Position {
    pub line: usize,
    pub column: usize,
}

impl fmt::Display for Position {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "line {}, column {}", self.line, self.column)
    }
}

/// What kind of text could not be read.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ErrorKind {
    /// Something other than a word, a comment or a space where a word should start.
    #[error("expected a word letter (A-Z)")]
    ExpectedLetter,
    /// A word letter with no number after it (`letter` as written).
    #[error("expected a number after `{letter}`")]
    ExpectedNumber { letter: char },
    /// `(` with no `)` before the end of the line.
    #[error("comment not closed by `)` on this line")]
    UnclosedComment,
    /// `/` after the start of the block.
    #[error("block delete `/` is only allowed at the start of a block")]
    MisplacedBlockDelete,
    /// `%` after the start of the line.
    #[error("program marker `%` is only allowed at the start of a line")]
    MisplacedPercent,
}

/// A syntax error: what, where, and the offending text.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{position}: {kind}, found `{text}`")]
pub struct NcError {
    pub position: Position,
    pub kind: ErrorKind,
    pub text: String,
}

/// Every line of a program that could not be read (parsing goes on after an error so
/// that a user sees all of them at once).
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub struct ProgramError {
    pub errors: Vec<NcError>,
}

impl fmt::Display for ProgramError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} line(s) could not be read", self.errors.len())?;
        for e in &self.errors {
            write!(f, "\n  {e}")?;
        }
        Ok(())
    }
}

/// Why an edit was refused (the block is left unchanged).
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum EditError {
    #[error("`{0}` is not a word letter (A-Z)")]
    NotALetter(char),
    #[error("{letter}{value} cannot be written as a G-code number (not finite)")]
    NotFinite { letter: char, value: f64 },
}
