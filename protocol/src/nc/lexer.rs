//! One line of a program into tokens. Every byte of the line belongs to exactly one
//! token and each token keeps its source text, which is what lets the writer give back
//! an unmodified line byte for byte.

use super::error::{ErrorKind, NcError, Position};
use super::number::{number_len, number_value};

/// What a token is.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum TokenKind<'a> {
    /// A letter and a number, possibly with spaces between them (`X1.5`, `x 1.5`).
    /// `letter` is upper-cased; `number` is the number's source text.
    Word {
        letter: char,
        value: f64,
        number: &'a str,
    },
    /// `( ... )`, delimiters included in the token text.
    ParenComment,
    /// `; ...` to the end of the line, `;` included in the token text.
    SemicolonComment,
    /// `/` at the start of the block: skip the block when block delete is on.
    BlockDelete,
    /// `%` at the start of a line: program start or end marker.
    ProgramMarker,
    /// Spaces and tabs between the other tokens.
    Space,
}

/// A token with its exact source text and where it starts.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Token<'a> {
    pub kind: TokenKind<'a>,
    pub text: &'a str,
    pub position: Position,
}

/// Tokens of one line, in order; stops after the first error. `line` must not contain
/// its line ending; `line_no` (1-based) is only used for positions.
pub fn lex(line: &str, line_no: usize) -> Lexer<'_> {
    Lexer {
        rest: line,
        position: Position {
            line: line_no,
            column: 1,
        },
        at_block_start: true,
        failed: false,
    }
}

/// The token iterator [`lex`] returns.
#[derive(Clone, Debug)]
pub struct Lexer<'a> {
    rest: &'a str,
    position: Position,
    /// Only spaces so far: where `/` and `%` are allowed.
    at_block_start: bool,
    failed: bool,
}

impl<'a> Iterator for Lexer<'a> {
    type Item = Result<Token<'a>, NcError>;

    fn next(&mut self) -> Option<Self::Item> {
        let first = self.rest.chars().next()?;
        if self.failed {
            return None;
        }
        let result = self.token(first);
        match &result {
            Ok(token) => self.advance(token),
            Err(_) => self.failed = true,
        }
        Some(result)
    }
}

impl<'a> Lexer<'a> {
    fn token(&self, first: char) -> Result<Token<'a>, NcError> {
        let (kind, len) = match first {
            ' ' | '\t' => (TokenKind::Space, space_len(self.rest.as_bytes())),
            '(' => (TokenKind::ParenComment, self.paren_comment_len()?),
            ';' => (TokenKind::SemicolonComment, self.rest.len()),
            '/' if self.at_block_start => (TokenKind::BlockDelete, 1),
            '/' => return Err(self.error(ErrorKind::MisplacedBlockDelete)),
            '%' if self.at_block_start => (TokenKind::ProgramMarker, 1),
            '%' => return Err(self.error(ErrorKind::MisplacedPercent)),
            c if c.is_ascii_alphabetic() => return self.word(c),
            _ => return Err(self.error(ErrorKind::ExpectedLetter)),
        };
        Ok(self.make(kind, len))
    }

    fn word(&self, letter: char) -> Result<Token<'a>, NcError> {
        let after_letter = &self.rest[1..];
        let gap = space_len(after_letter.as_bytes());
        let number_start = &after_letter[gap..];
        let len = number_len(number_start.as_bytes());
        if len == 0 {
            return Err(self.error(ErrorKind::ExpectedNumber { letter }));
        }
        let number = &number_start[..len];
        let kind = TokenKind::Word {
            letter: letter.to_ascii_uppercase(),
            value: number_value(number),
            number,
        };
        Ok(self.make(kind, 1 + gap + len))
    }

    fn paren_comment_len(&self) -> Result<usize, NcError> {
        match self.rest.find(')') {
            Some(close) => Ok(close + 1),
            None => Err(self.error(ErrorKind::UnclosedComment)),
        }
    }

    fn make(&self, kind: TokenKind<'a>, len: usize) -> Token<'a> {
        Token {
            kind,
            text: &self.rest[..len],
            position: self.position,
        }
    }

    fn advance(&mut self, token: &Token<'a>) {
        self.rest = &self.rest[token.text.len()..];
        self.position.column += token.text.chars().count();
        if token.kind != TokenKind::Space {
            self.at_block_start = false;
        }
    }

    /// An error at the current position, quoting the text up to the next space.
    fn error(&self, kind: ErrorKind) -> NcError {
        NcError {
            position: self.position,
            kind,
            text: offending_text(self.rest, kind),
        }
    }
}

fn space_len(s: &[u8]) -> usize {
    s.iter().take_while(|&&b| b == b' ' || b == b'\t').count()
}

/// What to quote in an error: the rest of an unclosed comment, otherwise the text up to
/// the next space (at most a dozen characters, enough to find it in the line).
fn offending_text(rest: &str, kind: ErrorKind) -> String {
    if kind == ErrorKind::UnclosedComment {
        return rest.to_string();
    }
    let first = rest.chars().take(1);
    let more = rest.chars().skip(1).take_while(|c| !c.is_whitespace());
    first.chain(more).take(12).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn kinds(line: &str) -> Vec<(String, &str)> {
        lex(line, 1)
            .map(|t| {
                let t = t.unwrap();
                let kind = match t.kind {
                    TokenKind::Word { letter, .. } => format!("word {letter}"),
                    other => format!("{other:?}"),
                };
                (kind, t.text)
            })
            .collect()
    }

    fn error(line: &str) -> NcError {
        lex(line, 7).find_map(Result::err).unwrap()
    }

    #[test]
    fn every_byte_belongs_to_one_token() {
        let line = " /N10 g1 x 1.50 ( move ) Y-.5;done ( not a comment";
        assert_eq!(
            kinds(line),
            vec![
                ("Space".into(), " "),
                ("BlockDelete".into(), "/"),
                ("word N".into(), "N10"),
                ("Space".into(), " "),
                ("word G".into(), "g1"),
                ("Space".into(), " "),
                ("word X".into(), "x 1.50"),
                ("Space".into(), " "),
                ("ParenComment".into(), "( move )"),
                ("Space".into(), " "),
                ("word Y".into(), "Y-.5"),
                ("SemicolonComment".into(), ";done ( not a comment"),
            ]
        );
        let text: String = lex(line, 1).map(|t| t.unwrap().text).collect();
        assert_eq!(text, line);
    }

    #[test]
    fn words_keep_number_text_and_value() {
        let t = lex("X+007.50", 1).next().unwrap().unwrap();
        assert_eq!(
            t.kind,
            TokenKind::Word {
                letter: 'X',
                value: 7.5,
                number: "+007.50"
            }
        );
    }

    #[test]
    fn percent_and_block_delete_only_at_the_start() {
        assert_eq!(kinds("%")[0].0, "ProgramMarker");
        assert_eq!(kinds("  % (start)")[1].0, "ProgramMarker");
        assert_eq!(error("G1 %").kind, ErrorKind::MisplacedPercent);
        assert_eq!(error("G1 /X1").kind, ErrorKind::MisplacedBlockDelete);
        assert_eq!(error("//G1").kind, ErrorKind::MisplacedBlockDelete);
    }

    #[test]
    fn errors_name_line_column_and_text() {
        let e = error("G1 X#1 Y2");
        assert_eq!(e.kind, ErrorKind::ExpectedNumber { letter: 'X' });
        assert_eq!(e.position, Position { line: 7, column: 4 });
        assert_eq!(e.text, "X#1");
        assert_eq!(
            e.to_string(),
            "line 7, column 4: expected a number after `X`, found `X#1`"
        );
        let e = error("(é) G1X1.2.3");
        assert_eq!(
            (e.kind, e.position.column, e.text.as_str()),
            (ErrorKind::ExpectedLetter, 11, ".3")
        );
        let e = error("G1 (open");
        assert_eq!(
            (e.kind, e.position.column, e.text.as_str()),
            (ErrorKind::UnclosedComment, 4, "(open")
        );
        assert_eq!(error("G1 )").kind, ErrorKind::ExpectedLetter);
        assert_eq!(
            error("G1 X").kind,
            ErrorKind::ExpectedNumber { letter: 'X' }
        );
        assert_eq!(error("G1 x -").text, "x");
    }

    #[test]
    fn lexing_stops_after_an_error() {
        let tokens: Vec<_> = lex("G1 # X1", 1).collect();
        assert_eq!(tokens.len(), 3);
        assert!(tokens[2].is_err());
    }
}
