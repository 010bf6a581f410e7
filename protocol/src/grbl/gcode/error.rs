//! GRBL's G-code status codes as a typed error, so the interpreter's steps say what
//! they refuse by name; [`GcodeError::code`] gives the number GRBL sends (`error:N`).

use super::super::codes::error_text;
use crate::nc::{ErrorKind, NcError};
use std::fmt;

/// Why GRBL refuses a G-code block, one variant per status code it can give for one,
/// numbered as GRBL numbers them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum GcodeError {
    ExpectedCommandLetter = 1,
    BadNumberFormat = 2,
    NegativeValue = 4,
    InvalidJogCommand = 16,
    UnsupportedCommand = 20,
    ModalGroupViolation = 21,
    UndefinedFeedRate = 22,
    CommandValueNotInteger = 23,
    AxisCommandConflict = 24,
    WordRepeated = 25,
    NoAxisWords = 26,
    InvalidLineNumber = 27,
    ValueWordMissing = 28,
    UnsupportedCoordSys = 29,
    G53InvalidMotionMode = 30,
    AxisWordsExist = 31,
    NoAxisWordsInPlane = 32,
    InvalidTarget = 33,
    ArcRadiusError = 34,
    NoOffsetsInPlane = 35,
    UnusedWords = 36,
    G43DynamicAxisError = 37,
    MaxValueExceeded = 38,
}

impl GcodeError {
    /// GRBL's number for it (`error:N`).
    pub fn code(&self) -> u8 {
        *self as u8
    }

    /// GRBL's reading of a word the nc lexer could not read: a letter with no number
    /// is error 2, anything else where a letter should be is error 1.
    pub(super) fn from_lex(error: &NcError) -> Self {
        match error.kind {
            ErrorKind::ExpectedNumber { letter } if letter.is_ascii_uppercase() => {
                GcodeError::BadNumberFormat
            }
            _ => GcodeError::ExpectedCommandLetter,
        }
    }
}

impl fmt::Display for GcodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "error:{} ({})", self.code(), error_text(self.code()))
    }
}

impl std::error::Error for GcodeError {}

impl From<GcodeError> for u8 {
    fn from(error: GcodeError) -> u8 {
        error.code()
    }
}

#[cfg(test)]
mod tests {
    use super::super::super::codes::status as e;
    use super::GcodeError::*;

    #[test]
    fn codes_are_grbls() {
        for (error, code) in [
            (ExpectedCommandLetter, e::EXPECTED_COMMAND_LETTER),
            (BadNumberFormat, e::BAD_NUMBER_FORMAT),
            (NegativeValue, e::NEGATIVE_VALUE),
            (InvalidJogCommand, e::INVALID_JOG_COMMAND),
            (UnsupportedCommand, e::UNSUPPORTED_COMMAND),
            (ModalGroupViolation, e::MODAL_GROUP_VIOLATION),
            (UndefinedFeedRate, e::UNDEFINED_FEED_RATE),
            (CommandValueNotInteger, e::COMMAND_VALUE_NOT_INTEGER),
            (AxisCommandConflict, e::AXIS_COMMAND_CONFLICT),
            (WordRepeated, e::WORD_REPEATED),
            (NoAxisWords, e::NO_AXIS_WORDS),
            (InvalidLineNumber, e::INVALID_LINE_NUMBER),
            (ValueWordMissing, e::VALUE_WORD_MISSING),
            (UnsupportedCoordSys, e::UNSUPPORTED_COORD_SYS),
            (G53InvalidMotionMode, e::G53_INVALID_MOTION_MODE),
            (AxisWordsExist, e::AXIS_WORDS_EXIST),
            (NoAxisWordsInPlane, e::NO_AXIS_WORDS_IN_PLANE),
            (InvalidTarget, e::INVALID_TARGET),
            (ArcRadiusError, e::ARC_RADIUS_ERROR),
            (NoOffsetsInPlane, e::NO_OFFSETS_IN_PLANE),
            (UnusedWords, e::UNUSED_WORDS),
            (G43DynamicAxisError, e::G43_DYNAMIC_AXIS_ERROR),
            (MaxValueExceeded, e::MAX_VALUE_EXCEEDED),
        ] {
            assert_eq!(error.code(), code, "{error:?}");
        }
    }
}
