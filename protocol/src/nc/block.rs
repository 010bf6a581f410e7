//! One block (one line) as a list of items in source order, editable word by word.
//!
//! Words and comments stay interleaved as written and spaces are items too, so writing a
//! block back gives its source text unless a word was edited; an edited word is written
//! as its letter (in the case it was written) and the number with the requested
//! decimals, everything else in the line is left alone.

use super::error::{EditError, NcError};
use super::lexer::{lex, Token, TokenKind};
use super::number::format_number;
use std::fmt;

/// A letter and a number. The source text is kept so that an untouched word is written
/// back byte-identical (`x 01.50` stays `x 01.50`).
#[derive(Clone, Debug, PartialEq)]
pub struct Word {
    letter: char,
    value: f64,
    text: String,
}

impl Word {
    /// A new word, written upper-case with exactly `decimals` decimals.
    pub fn new(letter: char, value: f64, decimals: usize) -> Result<Self, EditError> {
        if !letter.is_ascii_alphabetic() {
            return Err(EditError::NotALetter(letter));
        }
        let mut word = Word {
            letter: letter.to_ascii_uppercase(),
            value: 0.0,
            text: String::new(),
        };
        word.set_value(value, decimals)?;
        Ok(word)
    }

    /// The letter, upper-case whatever the source case.
    pub fn letter(&self) -> char {
        self.letter
    }

    pub fn value(&self) -> f64 {
        self.value
    }

    /// The word as it will be written: the source text until the value is set.
    pub fn text(&self) -> &str {
        &self.text
    }

    /// A new value with exactly `decimals` decimals; the letter keeps its source case.
    pub fn set_value(&mut self, value: f64, decimals: usize) -> Result<(), EditError> {
        let letter = self.text.chars().next().unwrap_or(self.letter);
        let number = format_number(value, decimals).ok_or(EditError::NotFinite {
            letter: self.letter,
            value,
        })?;
        self.value = value;
        self.text = format!("{letter}{number}");
        Ok(())
    }
}

impl fmt::Display for Word {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.text)
    }
}

/// A comment, held without its delimiters. The writer adds them back, so a `Paren` body
/// must not contain `)` and neither may contain a line break.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Comment {
    /// `(body)`
    Paren(String),
    /// `;body` to the end of the line.
    Semicolon(String),
}

impl Comment {
    pub fn body(&self) -> &str {
        match self {
            Comment::Paren(b) | Comment::Semicolon(b) => b,
        }
    }
}

impl fmt::Display for Comment {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Comment::Paren(b) => write!(f, "({b})"),
            Comment::Semicolon(b) => write!(f, ";{b}"),
        }
    }
}

/// One thing in a block, in source order.
#[derive(Clone, Debug, PartialEq)]
pub enum Item {
    Word(Word),
    Comment(Comment),
    /// Spaces and tabs, as written.
    Space(String),
    /// `%`: program start or end.
    ProgramMarker,
}

impl fmt::Display for Item {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Item::Word(w) => w.fmt(f),
            Item::Comment(c) => c.fmt(f),
            Item::Space(s) => f.write_str(s),
            Item::ProgramMarker => f.write_str("%"),
        }
    }
}

/// How a line ended in the source (the last line of a file may have none).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LineEnding {
    #[default]
    None,
    Lf,
    CrLf,
    Cr,
}

impl LineEnding {
    pub fn as_str(self) -> &'static str {
        match self {
            LineEnding::None => "",
            LineEnding::Lf => "\n",
            LineEnding::CrLf => "\r\n",
            LineEnding::Cr => "\r",
        }
    }
}

/// One line of a program: `[/] [N..] items`, and how the line ended.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Block {
    /// `/` at the start: the block is skipped when block delete is switched on.
    pub block_delete: bool,
    /// The `N` word when it is the first word of the block (an `N` further on is an
    /// ordinary word in `items`; whether that is legal is the dialect's business).
    pub line_no: Option<Word>,
    /// Everything after the line number, in source order.
    pub items: Vec<Item>,
    pub ending: LineEnding,
    /// Spaces before `/` and before the line number, to write them back.
    lead: Lead,
}

#[derive(Clone, Debug, Default, PartialEq)]
struct Lead {
    before_delete: String,
    before_line_no: String,
}

impl Block {
    /// An empty block.
    pub fn new() -> Self {
        Self::default()
    }

    /// Parses one line without its line ending; `line_no` (1-based) is for errors.
    pub fn parse(line: &str, line_no: usize) -> Result<Self, NcError> {
        let mut block = Block::new();
        let mut pending_space = String::new();
        for token in lex(line, line_no) {
            block.take_token(token?, &mut pending_space);
        }
        block.push_space(&mut pending_space);
        Ok(block)
    }

    /// Adds a token. Spaces wait in `pending` until the next token shows whether they
    /// precede `/`, the line number or an ordinary item.
    fn take_token(&mut self, token: Token<'_>, pending: &mut String) {
        match token.kind {
            TokenKind::Space => pending.push_str(token.text),
            TokenKind::BlockDelete => {
                self.block_delete = true;
                self.lead.before_delete = std::mem::take(pending);
            }
            TokenKind::Word { letter: 'N', .. }
                if self.items.is_empty() && self.line_no.is_none() =>
            {
                self.line_no = Some(word_of(&token));
                self.lead.before_line_no = std::mem::take(pending);
            }
            _ => {
                self.push_space(pending);
                self.items.push(item_of(&token));
            }
        }
    }

    fn push_space(&mut self, pending: &mut String) {
        if !pending.is_empty() {
            self.items.push(Item::Space(std::mem::take(pending)));
        }
    }

    /// All words in order, the line number first.
    pub fn words(&self) -> impl Iterator<Item = &Word> {
        self.line_no
            .iter()
            .chain(self.items.iter().filter_map(|i| match i {
                Item::Word(w) => Some(w),
                _ => None,
            }))
    }

    /// The first word with this letter (either case).
    pub fn word(&self, letter: char) -> Option<&Word> {
        let letter = letter.to_ascii_uppercase();
        self.words().find(|w| w.letter == letter)
    }

    /// The comments in order.
    pub fn comments(&self) -> impl Iterator<Item = &Comment> {
        self.items.iter().filter_map(|i| match i {
            Item::Comment(c) => Some(c),
            _ => None,
        })
    }

    /// No words: a blank line, only comments, or only `%`.
    pub fn has_no_words(&self) -> bool {
        self.words().next().is_none()
    }

    /// Sets the first word with this letter to `value` written with `decimals`
    /// decimals, or adds the word after the last word (before any comment) when the
    /// block has none, separated by a space if the block uses spaces.
    pub fn set_word(&mut self, letter: char, value: f64, decimals: usize) -> Result<(), EditError> {
        let upper = letter.to_ascii_uppercase();
        if let Some(word) = self.word_mut(upper) {
            return word.set_value(value, decimals);
        }
        let word = Word::new(letter, value, decimals)?;
        match upper {
            'N' => self.insert_line_no(word),
            _ => self.insert_word(word),
        }
        Ok(())
    }

    fn word_mut(&mut self, letter: char) -> Option<&mut Word> {
        let in_items = self.items.iter_mut().filter_map(|i| match i {
            Item::Word(w) => Some(w),
            _ => None,
        });
        self.line_no
            .iter_mut()
            .chain(in_items)
            .find(|w| w.letter == letter)
    }

    fn separator(&self) -> &'static str {
        let spaced = self.items.iter().any(|i| matches!(i, Item::Space(_)));
        if spaced {
            " "
        } else {
            ""
        }
    }

    fn insert_word(&mut self, word: Word) {
        let sep = self.separator();
        let last_word = self.items.iter().rposition(|i| matches!(i, Item::Word(_)));
        let mut new_items = vec![Item::Word(word)];
        let at = match last_word {
            Some(i) => {
                new_items.insert(0, Item::Space(sep.into()));
                i + 1
            }
            None => {
                let first_comment = self
                    .items
                    .iter()
                    .position(|i| matches!(i, Item::Comment(_)));
                let at = first_comment.unwrap_or(self.items.len());
                if at < self.items.len() {
                    new_items.push(Item::Space(sep.into()));
                }
                at
            }
        };
        new_items.retain(|i| !matches!(i, Item::Space(s) if s.is_empty()));
        self.items.splice(at..at, new_items);
    }

    fn insert_line_no(&mut self, word: Word) {
        let sep = self.separator();
        let starts_with_space = matches!(self.items.first(), Some(Item::Space(_)));
        if !sep.is_empty() && !starts_with_space && !self.items.is_empty() {
            self.items.insert(0, Item::Space(sep.into()));
        }
        self.line_no = Some(word);
    }

    /// Removes the first word with this letter and one space next to it (the one before
    /// it if any, else the one after), so that `G1 X1 Y2` becomes `G1 Y2`.
    pub fn remove_word(&mut self, letter: char) -> Option<Word> {
        let letter = letter.to_ascii_uppercase();
        if self.line_no.as_ref().is_some_and(|w| w.letter == letter) {
            if matches!(self.items.first(), Some(Item::Space(_))) {
                self.items.remove(0);
            }
            return self.line_no.take();
        }
        let at = self
            .items
            .iter()
            .position(|i| matches!(i, Item::Word(w) if w.letter == letter))?;
        let Item::Word(word) = self.items.remove(at) else {
            unreachable!("position matched a word")
        };
        self.remove_space_next_to(at);
        Some(word)
    }

    /// Removes the space before index `at` (where a removed item was), or else at it.
    fn remove_space_next_to(&mut self, at: usize) {
        let is_space = |i: Option<&Item>| matches!(i, Some(Item::Space(_)));
        if at > 0 && is_space(self.items.get(at - 1)) {
            self.items.remove(at - 1);
        } else if is_space(self.items.get(at)) {
            self.items.remove(at);
        }
    }
}

fn word_of(token: &Token<'_>) -> Word {
    let TokenKind::Word { letter, value, .. } = token.kind else {
        unreachable!("called for word tokens only")
    };
    Word {
        letter,
        value,
        text: token.text.to_string(),
    }
}

fn item_of(token: &Token<'_>) -> Item {
    let text = token.text;
    match token.kind {
        TokenKind::Word { .. } => Item::Word(word_of(token)),
        TokenKind::ParenComment => Item::Comment(Comment::Paren(text[1..text.len() - 1].into())),
        TokenKind::SemicolonComment => Item::Comment(Comment::Semicolon(text[1..].into())),
        TokenKind::ProgramMarker => Item::ProgramMarker,
        TokenKind::Space | TokenKind::BlockDelete => unreachable!("kept out of items"),
    }
}

/// The block as it will be written, without its line ending.
impl fmt::Display for Block {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.block_delete {
            write!(f, "{}/", self.lead.before_delete)?;
        }
        if let Some(n) = &self.line_no {
            write!(f, "{}{n}", self.lead.before_line_no)?;
        }
        self.items.iter().try_for_each(|i| i.fmt(f))
    }
}
