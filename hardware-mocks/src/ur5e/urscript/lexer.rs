//! URScript tokens: the lexer.
//!
//! Lexical rules as the URScript manual ("The URScript Programming Language", sections
//! "Numbers, Variables, and Types" and "Flow of Control") uses them: statements end at the end
//! of a line, blocks open with a line ending in `:` and close with `end`, `#` starts a comment
//! that runs to the end of the line, strings are quoted with `"` or `'`, numbers are integers
//! (`42`) or floats (`0.25`, `1e-3`, `2.5E+2`), and a pose literal is `p[…]` (the letter `p`
//! directly followed by `[`). Inside `(…)` and `[…]` a line break does not end the statement.

use super::ScriptError;

/// One token and the 1-based line it starts on.
#[derive(Debug, Clone, PartialEq)]
pub struct Token {
    pub kind: Tok,
    pub line: u32,
}

#[derive(Debug, Clone, PartialEq)]
pub enum Tok {
    Ident(String),
    Int(i32),
    Float(f64),
    Str(String),
    /// `p[`: the opening of a pose literal.
    PoseOpen,
    LParen,
    RParen,
    LBracket,
    RBracket,
    Comma,
    Colon,
    Assign,
    Eq,
    Ne,
    Lt,
    Le,
    Gt,
    Ge,
    Plus,
    Minus,
    Star,
    Slash,
    Percent,
    /// End of a statement (a line break outside brackets).
    Newline,
}

impl Tok {
    /// Whether this is the identifier (or keyword) `word`.
    pub fn is_word(&self, word: &str) -> bool {
        matches!(self, Tok::Ident(w) if w == word)
    }
}

/// Splits `text` into tokens. Comments and blank lines produce nothing; consecutive line
/// breaks collapse into one [`Tok::Newline`].
pub fn lex(text: &str) -> Result<Vec<Token>, ScriptError> {
    let chars: Vec<char> = text.chars().collect();
    let mut out: Vec<Token> = Vec::new();
    let mut i = 0;
    let mut line: u32 = 1;
    let mut depth: i32 = 0;
    let err = |line: u32, msg: String| ScriptError::Syntax { line, msg };
    while i < chars.len() {
        let c = chars[i];
        let simple = |k: Tok| Token { kind: k, line };
        match c {
            '\n' => {
                if depth <= 0 && out.last().is_some_and(|t| t.kind != Tok::Newline) {
                    out.push(simple(Tok::Newline));
                }
                line += 1;
                i += 1;
            }
            ' ' | '\t' | '\r' => i += 1,
            '#' => {
                while i < chars.len() && chars[i] != '\n' {
                    i += 1;
                }
            }
            '"' | '\'' => {
                let start_line = line;
                let mut s = String::new();
                i += 1;
                loop {
                    match chars.get(i) {
                        None | Some('\n') => {
                            return Err(err(start_line, "unterminated string".into()));
                        }
                        Some(&q) if q == c => break,
                        Some(&ch) => s.push(ch),
                    }
                    i += 1;
                }
                i += 1;
                out.push(Token {
                    kind: Tok::Str(s),
                    line: start_line,
                });
            }
            '0'..='9' | '.' if c != '.' || chars.get(i + 1).is_some_and(char::is_ascii_digit) => {
                let (tok, next) = number(&chars, i).map_err(|m| err(line, m))?;
                out.push(simple(tok));
                i = next;
            }
            c if c.is_ascii_alphabetic() || c == '_' => {
                let start = i;
                while i < chars.len() && (chars[i].is_ascii_alphanumeric() || chars[i] == '_') {
                    i += 1;
                }
                let word: String = chars[start..i].iter().collect();
                if word == "p" && chars.get(i) == Some(&'[') {
                    i += 1;
                    depth += 1;
                    out.push(simple(Tok::PoseOpen));
                } else {
                    out.push(simple(Tok::Ident(word)));
                }
            }
            _ => {
                let two = |next: char| chars.get(i + 1) == Some(&next);
                let (kind, len) = match c {
                    '(' => (Tok::LParen, 1),
                    ')' => (Tok::RParen, 1),
                    '[' => (Tok::LBracket, 1),
                    ']' => (Tok::RBracket, 1),
                    ',' => (Tok::Comma, 1),
                    ':' => (Tok::Colon, 1),
                    '=' if two('=') => (Tok::Eq, 2),
                    '=' => (Tok::Assign, 1),
                    '!' if two('=') => (Tok::Ne, 2),
                    '<' if two('=') => (Tok::Le, 2),
                    '<' => (Tok::Lt, 1),
                    '>' if two('=') => (Tok::Ge, 2),
                    '>' => (Tok::Gt, 1),
                    '+' => (Tok::Plus, 1),
                    '-' => (Tok::Minus, 1),
                    '*' => (Tok::Star, 1),
                    '/' => (Tok::Slash, 1),
                    '%' => (Tok::Percent, 1),
                    other => return Err(err(line, format!("unexpected character {other:?}"))),
                };
                match kind {
                    Tok::LParen | Tok::LBracket => depth += 1,
                    Tok::RParen | Tok::RBracket => depth -= 1,
                    _ => {}
                }
                out.push(simple(kind));
                i += len;
            }
        }
    }
    if let Some(last) = out.last().filter(|t| t.kind != Tok::Newline) {
        let line = last.line;
        out.push(Token {
            kind: Tok::Newline,
            line,
        });
    }
    Ok(out)
}

/// A number literal starting at `i`: the token and the index after it.
fn number(chars: &[char], mut i: usize) -> Result<(Tok, usize), String> {
    let start = i;
    let digits = |i: &mut usize| {
        while *i < chars.len() && chars[*i].is_ascii_digit() {
            *i += 1;
        }
    };
    digits(&mut i);
    let mut float = false;
    if chars.get(i) == Some(&'.') {
        float = true;
        i += 1;
        digits(&mut i);
    }
    if matches!(chars.get(i), Some('e' | 'E')) {
        let mut j = i + 1;
        if matches!(chars.get(j), Some('+' | '-')) {
            j += 1;
        }
        if chars.get(j).is_some_and(char::is_ascii_digit) {
            float = true;
            i = j;
            digits(&mut i);
        }
    }
    let text: String = chars[start..i].iter().collect();
    let tok = if float {
        Tok::Float(
            text.parse()
                .map_err(|_| format!("bad number literal {text:?}"))?,
        )
    } else {
        Tok::Int(
            text.parse()
                .map_err(|_| format!("integer literal {text} does not fit in 32 bits"))?,
        )
    };
    Ok((tok, i))
}
