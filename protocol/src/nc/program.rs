//! A whole program text: one [`Block`] per line, with its line ending, so that writing
//! it back gives the same bytes.

use super::block::{Block, LineEnding};
use super::error::ProgramError;
use std::fmt;

/// A parsed program. `blocks[k]` is line `k + 1` of the text.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Program {
    pub blocks: Vec<Block>,
}

impl Program {
    /// Parses every line; on errors, reports each line that could not be read (its
    /// first error) rather than only the first one.
    pub fn parse(text: &str) -> Result<Self, ProgramError> {
        let mut blocks = Vec::new();
        let mut errors = Vec::new();
        for (index, (line, ending)) in split_lines(text).enumerate() {
            match Block::parse(line, index + 1) {
                Ok(mut block) => {
                    block.ending = ending;
                    blocks.push(block);
                }
                Err(e) => errors.push(e),
            }
        }
        if errors.is_empty() {
            Ok(Program { blocks })
        } else {
            Err(ProgramError { errors })
        }
    }
}

/// Lines and how each ended (`\n`, `\r\n` or a lone `\r`). A final line ending does
/// not start another (empty) line, so `"G0\n"` is one line.
pub fn split_lines(text: &str) -> impl Iterator<Item = (&str, LineEnding)> {
    let mut rest = text;
    std::iter::from_fn(move || {
        if rest.is_empty() {
            return None;
        }
        let Some(end) = rest.find(['\n', '\r']) else {
            return Some((std::mem::take(&mut rest), LineEnding::None));
        };
        let ending = match &rest[end..] {
            r if r.starts_with("\r\n") => LineEnding::CrLf,
            r if r.starts_with('\r') => LineEnding::Cr,
            _ => LineEnding::Lf,
        };
        let line = &rest[..end];
        rest = &rest[end + ending.as_str().len()..];
        Some((line, ending))
    })
}

/// Writes every block with its line ending. A block without one that is not the last
/// (one inserted by a program rewrite) gets the ending of the block before it, or `\n`.
impl fmt::Display for Program {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut previous = LineEnding::Lf;
        for (k, block) in self.blocks.iter().enumerate() {
            let is_last = k + 1 == self.blocks.len();
            let ending = match block.ending {
                LineEnding::None if !is_last => previous,
                e => e,
            };
            write!(f, "{block}{}", ending.as_str())?;
            if ending != LineEnding::None {
                previous = ending;
            }
        }
        Ok(())
    }
}
