//! One line of an RS274/NGC program read as LinuxCNC's interpreter reads it
//! (`interp_read.cc`): spaces and tabs dropped and letters lower-cased outside comments
//! (`close_and_downcase`), comments removed, then the line is an O-word statement or a
//! list of words and parameter settings, every value an expression tree to be evaluated
//! later (by [`super::flow`]).

use super::NgcError;

/// A parameter reference: `#12`, `#[expr]`, `##1`, `#<name>`.
#[derive(Clone, Debug, PartialEq)]
pub enum Param {
    /// A numbered parameter; the index is an expression (`#[1+2]`, `##1`).
    Numbered(Box<Expr>),
    /// A named parameter, lower-case as LinuxCNC stores it (`_` first: global).
    Named(String),
}

/// A unary function of LinuxCNC's expressions.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Func {
    Abs,
    Acos,
    Asin,
    Cos,
    Exp,
    Fix,
    Fup,
    Ln,
    Round,
    Sin,
    Sqrt,
    Tan,
}

/// Binary operators, LinuxCNC's precedence (`interp_internal.cc`, `precedence`): `**`
/// 6; `* / MOD` 5; `+ -` 4; `EQ NE GT GE LT LE` 3; `AND OR XOR` 2; all left-associative.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Op {
    Pow,
    Mul,
    Div,
    Mod,
    Add,
    Sub,
    Eq,
    Ne,
    Gt,
    Ge,
    Lt,
    Le,
    And,
    Or,
    Xor,
}

impl Op {
    fn precedence(self) -> u8 {
        match self {
            Op::Pow => 6,
            Op::Mul | Op::Div | Op::Mod => 5,
            Op::Add | Op::Sub => 4,
            Op::Eq | Op::Ne | Op::Gt | Op::Ge | Op::Lt | Op::Le => 3,
            Op::And | Op::Or | Op::Xor => 2,
        }
    }
}

/// A value as written: evaluated when the line runs.
#[derive(Clone, Debug, PartialEq)]
pub enum Expr {
    Number(f64),
    Param(Param),
    Neg(Box<Expr>),
    Unary(Func, Box<Expr>),
    /// `ATAN[y]/[x]`, degrees.
    Atan(Box<Expr>, Box<Expr>),
    /// `EXISTS[#<name>]`.
    Exists(String),
    Binary(Op, Box<Expr>, Box<Expr>),
}

/// The O-word statements.
#[derive(Clone, Debug, PartialEq)]
pub enum OKind {
    Sub,
    EndSub(Option<Expr>),
    Return(Option<Expr>),
    Call(Vec<Expr>),
    Do,
    While(Expr),
    EndWhile,
    If(Expr),
    ElseIf(Expr),
    Else,
    EndIf,
    Repeat(Expr),
    EndRepeat,
    Break,
    Continue,
}

/// One item of an ordinary line.
#[derive(Clone, Debug, PartialEq)]
pub enum Item {
    /// A word: its letter (lower-case) and value.
    Word(char, Expr),
    /// `#ref = expr`: takes effect after the whole line is read.
    Set(Param, Expr),
}

/// A line's content.
#[derive(Clone, Debug, PartialEq)]
pub enum Statement {
    /// Blank or only comments.
    Empty,
    /// `%` alone: program start and end marker.
    Percent,
    /// `o<name> keyword ...`; the name lower-case (`100` or `<name>`).
    O(String, OKind),
    Words(Vec<Item>),
}

/// A line read: whether it starts with `/`, and what it holds.
#[derive(Clone, Debug, PartialEq)]
pub struct Line {
    pub block_delete: bool,
    pub statement: Statement,
}

/// The most characters of one line (LinuxCNC's `LINELEN` is 256).
pub const MAX_LINE: usize = 256;

/// Deepest nesting of brackets and parameter indirections read (a bound for hostile
/// input; LinuxCNC's own stack is smaller).
const MAX_DEPTH: usize = 64;

/// Reads one line (without its line ending); `line` numbers errors.
pub fn read_line(text: &str, line: usize) -> Result<Line, NgcError> {
    let fail = |m: String| NgcError::new(line, text, m);
    if text.chars().count() > MAX_LINE {
        return Err(fail(format!(
            "the line has more than {MAX_LINE} characters, LinuxCNC's longest"
        )));
    }
    let squeezed = squeeze(text).map_err(fail)?;
    if squeezed == "%" {
        return Ok(Line {
            block_delete: false,
            statement: Statement::Percent,
        });
    }
    let mut r = Reader {
        s: squeezed.as_bytes(),
        at: 0,
        depth: 0,
    };
    let block_delete = r.eat(b'/');
    // A line number N (integer, LinuxCNC reads and ignores it).
    if r.peek() == Some(b'n') {
        r.at += 1;
        let start = r.at;
        while r.peek().is_some_and(|c| c.is_ascii_digit() || c == b'.') {
            r.at += 1;
        }
        if r.at == start {
            return Err(fail("`N` without a line number".into()));
        }
    }
    let statement = if r.at == r.s.len() {
        Statement::Empty
    } else if r.peek() == Some(b'o') {
        r.o_statement().map_err(fail)?
    } else {
        Statement::Words(r.words().map_err(fail)?)
    };
    Ok(Line {
        block_delete,
        statement,
    })
}

/// The line without spaces, tabs and comments, lower-case (LinuxCNC's
/// `close_and_downcase`, then its comments skipped). A `(` inside a comment and an
/// unclosed comment are errors, as in LinuxCNC.
fn squeeze(text: &str) -> Result<String, String> {
    let mut out = String::with_capacity(text.len());
    let mut chars = text.chars();
    while let Some(c) = chars.next() {
        match c {
            ' ' | '\t' => {}
            ';' => break,
            '(' => loop {
                match chars.next() {
                    None => return Err("comment not closed by `)` on this line".into()),
                    Some(')') => break,
                    Some('(') => return Err("nested comment: `(` inside a comment".into()),
                    Some(_) => {}
                }
            },
            c if c.is_ascii() && !c.is_ascii_control() => out.push(c.to_ascii_lowercase()),
            c => {
                return Err(format!(
                    "`{}` outside a comment: LinuxCNC reads ASCII only",
                    c.escape_default()
                ))
            }
        }
    }
    Ok(out)
}

struct Reader<'a> {
    s: &'a [u8],
    at: usize,
    depth: usize,
}

impl Reader<'_> {
    fn peek(&self) -> Option<u8> {
        self.s.get(self.at).copied()
    }

    fn eat(&mut self, c: u8) -> bool {
        if self.peek() == Some(c) {
            self.at += 1;
            true
        } else {
            false
        }
    }

    fn rest_starts(&self, word: &str) -> bool {
        self.s[self.at..].starts_with(word.as_bytes())
    }

    fn near(&self) -> String {
        let rest = &self.s[self.at.min(self.s.len())..];
        let shown: String = rest.iter().take(12).map(|&b| b as char).collect();
        if shown.is_empty() {
            "the end of the line".into()
        } else {
            format!("`{shown}`")
        }
    }

    fn o_statement(&mut self) -> Result<Statement, String> {
        self.at += 1;
        let name = if self.eat(b'<') {
            let start = self.at;
            while self.peek().is_some_and(|c| c != b'>') {
                self.at += 1;
            }
            if !self.eat(b'>') || self.at - 1 == start {
                return Err("an O-word name `<...>` not closed by `>`".into());
            }
            format!("<{}>", String::from_utf8_lossy(&self.s[start..self.at - 1]))
        } else {
            let start = self.at;
            while self.peek().is_some_and(|c| c.is_ascii_digit()) {
                self.at += 1;
            }
            if self.at == start {
                return Err(format!(
                    "an O-word needs a number or a <name>, found {}",
                    self.near()
                ));
            }
            String::from_utf8_lossy(&self.s[start..self.at])
                .trim_start_matches('0')
                .to_string()
        };
        // Longest keywords first (`endsub` before `end`, `elseif` before `else`).
        const KEYWORDS: [&str; 15] = [
            "endrepeat",
            "endwhile",
            "continue",
            "elseif",
            "endsub",
            "return",
            "repeat",
            "endif",
            "while",
            "break",
            "call",
            "else",
            "sub",
            "do",
            "if",
        ];
        let Some(keyword) = KEYWORDS.iter().find(|k| self.rest_starts(k)) else {
            return Err(format!(
                "o{name} without a keyword LinuxCNC knows (sub, endsub, call, do, while, endwhile, if, elseif, else, endif, repeat, endrepeat, break, continue, return), found {}",
                self.near()
            ));
        };
        self.at += keyword.len();
        let kind = match *keyword {
            "sub" => OKind::Sub,
            "endsub" => OKind::EndSub(self.optional_bracket()?),
            "return" => OKind::Return(self.optional_bracket()?),
            "call" => {
                let mut args = Vec::new();
                while self.peek() == Some(b'[') {
                    if args.len() == 30 {
                        return Err("a call with more than 30 arguments".into());
                    }
                    args.push(self.bracket()?);
                }
                OKind::Call(args)
            }
            "do" => OKind::Do,
            "while" => OKind::While(self.required_bracket(keyword)?),
            "endwhile" => OKind::EndWhile,
            "if" => OKind::If(self.required_bracket(keyword)?),
            "elseif" => OKind::ElseIf(self.required_bracket(keyword)?),
            "else" => OKind::Else,
            "endif" => OKind::EndIf,
            "repeat" => OKind::Repeat(self.required_bracket(keyword)?),
            "endrepeat" => OKind::EndRepeat,
            "break" => OKind::Break,
            _ => OKind::Continue,
        };
        if self.at != self.s.len() {
            return Err(format!(
                "o{name} {keyword} followed by {}: other words on an O-word line are not defined in LinuxCNC",
                self.near()
            ));
        }
        Ok(Statement::O(name, kind))
    }

    fn optional_bracket(&mut self) -> Result<Option<Expr>, String> {
        if self.peek() == Some(b'[') {
            Ok(Some(self.bracket()?))
        } else {
            Ok(None)
        }
    }

    fn required_bracket(&mut self, keyword: &str) -> Result<Expr, String> {
        if self.peek() != Some(b'[') {
            return Err(format!("`{keyword}` needs a condition in `[...]`"));
        }
        self.bracket()
    }

    fn words(&mut self) -> Result<Vec<Item>, String> {
        let mut items = Vec::new();
        while let Some(c) = self.peek() {
            if c == b'#' {
                self.at += 1;
                let p = self.param()?;
                if !self.eat(b'=') {
                    return Err(format!(
                        "a parameter where a word should start must be set (`#..=value`), found {}",
                        self.near()
                    ));
                }
                let v = self.value()?;
                items.push(Item::Set(p, v));
                continue;
            }
            if !c.is_ascii_lowercase() || matches!(c, b'n' | b'o') {
                return Err(format!("expected a word letter, found {}", self.near()));
            }
            self.at += 1;
            let v = self.value()?;
            items.push(Item::Word(c as char, v));
        }
        Ok(items)
    }

    /// A real value: a number, `[expr]`, a parameter, a unary function, or a sign
    /// before one of these (`read_real_value`).
    fn value(&mut self) -> Result<Expr, String> {
        self.depth += 1;
        if self.depth > MAX_DEPTH {
            return Err(format!("expressions nested deeper than {MAX_DEPTH}"));
        }
        let v = self.value_inner();
        self.depth -= 1;
        v
    }

    fn value_inner(&mut self) -> Result<Expr, String> {
        let Some(c) = self.peek() else {
            return Err("a value is missing at the end of the line".into());
        };
        let next = self.s.get(self.at + 1).copied();
        let digit_next = next.is_some_and(|n| n.is_ascii_digit() || n == b'.');
        match c {
            b'[' => self.bracket(),
            b'#' => {
                self.at += 1;
                Ok(Expr::Param(self.param()?))
            }
            b'+' if !digit_next => {
                self.at += 1;
                self.value()
            }
            b'-' if !digit_next => {
                self.at += 1;
                Ok(Expr::Neg(Box::new(self.value()?)))
            }
            b'a'..=b'z' => self.unary(),
            _ => self.number().map(Expr::Number),
        }
    }

    /// `read_real_number`: an optional sign, digits with at most one point, at least
    /// one digit; no exponent.
    fn number(&mut self) -> Result<f64, String> {
        let start = self.at;
        if matches!(self.peek(), Some(b'+' | b'-')) {
            self.at += 1;
        }
        let mut digits = 0;
        let mut point = false;
        while let Some(c) = self.peek() {
            if c.is_ascii_digit() {
                digits += 1;
            } else if c == b'.' && !point {
                point = true;
            } else {
                break;
            }
            self.at += 1;
        }
        if digits == 0 {
            self.at = start;
            return Err(format!("expected a number, found {}", self.near()));
        }
        let text = std::str::from_utf8(&self.s[start..self.at]).unwrap_or("");
        text.parse::<f64>()
            .map_err(|_| format!("`{text}` is not a number"))
    }

    /// `[expr]`: operands and binary operators, reduced by precedence
    /// (`read_real_expression`).
    fn bracket(&mut self) -> Result<Expr, String> {
        if !self.eat(b'[') {
            return Err(format!("expected `[`, found {}", self.near()));
        }
        self.depth += 1;
        if self.depth > MAX_DEPTH {
            return Err(format!("expressions nested deeper than {MAX_DEPTH}"));
        }
        let mut values = vec![self.value()?];
        let mut ops: Vec<Op> = Vec::new();
        loop {
            if self.eat(b']') {
                break;
            }
            let op = self.operator()?;
            while ops
                .last()
                .is_some_and(|top| top.precedence() >= op.precedence())
            {
                reduce(&mut values, &mut ops);
            }
            ops.push(op);
            values.push(self.value()?);
        }
        while !ops.is_empty() {
            reduce(&mut values, &mut ops);
        }
        self.depth -= 1;
        Ok(values.pop().unwrap_or(Expr::Number(0.0)))
    }

    fn operator(&mut self) -> Result<Op, String> {
        const OPS: [(&str, Op); 15] = [
            ("**", Op::Pow),
            ("*", Op::Mul),
            ("/", Op::Div),
            ("mod", Op::Mod),
            ("+", Op::Add),
            ("-", Op::Sub),
            ("eq", Op::Eq),
            ("ne", Op::Ne),
            ("gt", Op::Gt),
            ("ge", Op::Ge),
            ("lt", Op::Lt),
            ("le", Op::Le),
            ("and", Op::And),
            ("or", Op::Or),
            ("xor", Op::Xor),
        ];
        for (text, op) in OPS {
            if self.rest_starts(text) {
                self.at += text.len();
                return Ok(op);
            }
        }
        if self.at >= self.s.len() {
            return Err("`[` not closed by `]` on this line".into());
        }
        Err(format!(
            "expected a binary operator or `]`, found {}",
            self.near()
        ))
    }

    fn unary(&mut self) -> Result<Expr, String> {
        const FUNCS: [(&str, Func); 12] = [
            ("abs", Func::Abs),
            ("acos", Func::Acos),
            ("asin", Func::Asin),
            ("cos", Func::Cos),
            ("exp", Func::Exp),
            ("fix", Func::Fix),
            ("fup", Func::Fup),
            ("ln", Func::Ln),
            ("round", Func::Round),
            ("sin", Func::Sin),
            ("sqrt", Func::Sqrt),
            ("tan", Func::Tan),
        ];
        if self.rest_starts("atan") {
            self.at += 4;
            let y = self.bracket()?;
            if !self.eat(b'/') {
                return Err("ATAN needs `ATAN[y]/[x]`".into());
            }
            let x = self.bracket()?;
            return Ok(Expr::Atan(Box::new(y), Box::new(x)));
        }
        if self.rest_starts("exists") {
            self.at += 6;
            if !(self.eat(b'[') && self.eat(b'#') && self.peek() == Some(b'<')) {
                return Err("EXISTS needs `EXISTS[#<name>]`".into());
            }
            let Param::Named(name) = self.param()? else {
                unreachable!("`<` starts a name")
            };
            if !self.eat(b']') {
                return Err("EXISTS needs `EXISTS[#<name>]`".into());
            }
            return Ok(Expr::Exists(name));
        }
        for (text, f) in FUNCS {
            if self.rest_starts(text) {
                self.at += text.len();
                if self.peek() != Some(b'[') {
                    return Err(format!(
                        "`{}` needs its argument in `[...]`",
                        text.to_uppercase()
                    ));
                }
                return Ok(Expr::Unary(f, Box::new(self.bracket()?)));
            }
        }
        Err(format!(
            "expected a value, found {} (not a function LinuxCNC knows)",
            self.near()
        ))
    }

    /// After `#`: `<name>`, or an index (a number, `[expr]` or another parameter).
    fn param(&mut self) -> Result<Param, String> {
        if self.eat(b'<') {
            let start = self.at;
            while self.peek().is_some_and(|c| c != b'>') {
                self.at += 1;
            }
            if !self.eat(b'>') || self.at - 1 == start {
                return Err("a parameter name `#<...>` not closed by `>`".into());
            }
            return Ok(Param::Named(
                String::from_utf8_lossy(&self.s[start..self.at - 1]).into_owned(),
            ));
        }
        self.depth += 1;
        if self.depth > MAX_DEPTH {
            return Err(format!("parameters nested deeper than {MAX_DEPTH}"));
        }
        let index = match self.peek() {
            Some(b'[') => self.bracket()?,
            Some(b'#') => {
                self.at += 1;
                Expr::Param(self.param()?)
            }
            _ => {
                let start = self.at;
                while self.peek().is_some_and(|c| c.is_ascii_digit()) {
                    self.at += 1;
                }
                if self.at == start {
                    return Err(format!(
                        "expected a parameter number or <name> after `#`, found {}",
                        self.near()
                    ));
                }
                let text = std::str::from_utf8(&self.s[start..self.at]).unwrap_or("");
                Expr::Number(text.parse::<f64>().map_err(|_| format!("`#{text}`"))?)
            }
        };
        self.depth -= 1;
        Ok(Param::Numbered(Box::new(index)))
    }
}

fn reduce(values: &mut Vec<Expr>, ops: &mut Vec<Op>) {
    let (Some(op), Some(r), Some(l)) = (ops.pop(), values.pop(), values.pop()) else {
        return;
    };
    values.push(Expr::Binary(op, Box::new(l), Box::new(r)));
}
