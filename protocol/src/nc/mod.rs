//! A dialect-neutral RS-274 (ISO 6983) layer, sans-IO: lex a block into tokens, parse a
//! program into blocks that keep every comment and every space, edit words, and write
//! the program back.
//!
//! Why a separate layer: rewriting a user's program (error-map compensation, 5-axis
//! rewriting, a live pass-through) must change only the numbers it means to change.
//! An untouched word keeps the text it was written with (`x 1.50` stays `x 1.50`), so
//! `Program::parse(text)?.to_string() == text` for any program this layer accepts,
//! whatever its line endings, spacing, letter case or comments.
//!
//! What this layer knows is the block syntax common to the dialects: words (a letter
//! and a number), `( )` and `;` comments, block delete `/`, the `N` line number, `%`
//! program markers. It knows nothing of modal groups, legal letters or value limits:
//! those belong to a dialect on top (see [`crate::grbl::gcode`] for GRBL 1.1).
//!
//! * [`lexer`]: one line into [`Token`]s, each with its exact source text and column.
//! * [`block`]: [`Block`], [`Word`], [`Comment`], [`Item`]: the parsed line, editable.
//! * [`program`]: [`Program`], a whole text with per-line errors.
//! * [`number`]: [`format_number`], how edited numbers are written.
//! * [`error`]: [`NcError`] (what and where), [`EditError`], [`ProgramError`].

pub mod block;
pub mod error;
pub mod lexer;
pub mod number;
pub mod program;

pub use block::{Block, Comment, Item, LineEnding, Word};
pub use error::{EditError, ErrorKind, NcError, Position, ProgramError};
pub use lexer::{lex, Lexer, Token, TokenKind};
pub use number::format_number;
pub use program::{split_lines, Program};

#[cfg(test)]
mod tests;
