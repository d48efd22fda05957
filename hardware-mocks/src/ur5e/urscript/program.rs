//! A script's text made into a [`Program`] (lexed, parsed, compiled), and whether text received
//! so far is a whole script ([`is_complete`], [`is_closed`]).

use std::sync::Arc;

use super::compile::{self, Code};
use super::interp::Interpreter;
use super::{ScriptError, lexer, parser};

/// A compiled script, ready to be started any number of times.
#[derive(Debug, Clone)]
pub struct Program {
    /// The name of the script's first `def` ("script" if it has none): what the dashboard
    /// server reports as the loaded program.
    pub name: String,
    pub code: Arc<Code>,
    lines: Arc<Vec<String>>,
}

impl Program {
    /// Lexes, parses and compiles `text`.
    pub fn parse(text: &str) -> Result<Self, ScriptError> {
        let lines: Vec<String> = text.lines().map(|l| l.trim().to_owned()).collect();
        let with_statement = |e: ScriptError| match e {
            ScriptError::Syntax { line, msg } => {
                let stmt = lines
                    .get((line as usize).wrapping_sub(1))
                    .map_or("", String::as_str);
                ScriptError::Syntax {
                    line,
                    msg: format!("{msg} (in `{stmt}`)"),
                }
            }
        };
        let tokens = lexer::lex(text).map_err(with_statement)?;
        let top = parser::parse(&tokens).map_err(with_statement)?;
        let code = compile::compile(&top).map_err(with_statement)?;
        let name = code
            .funcs
            .iter()
            .find(|f| !f.is_thread)
            .map_or_else(|| "script".to_owned(), |f| f.name.clone());
        Ok(Self {
            name,
            code: Arc::new(code),
            lines: Arc::new(lines),
        })
    }

    /// A fresh run of the program.
    pub fn start(&self) -> Interpreter {
        Interpreter::new(self.code.clone())
    }

    /// Source line `line` (1-based), trimmed: the statement an error names.
    pub fn line(&self, line: u32) -> &str {
        self.lines
            .get((line as usize).wrapping_sub(1))
            .map_or("", String::as_str)
    }
}

/// Whether `text` received so far on the secondary interface is a whole script: it lexes,
/// ends at a line break, every block is closed, and the last top-level item is a statement
/// rather than a definition (the rig's program ends with the call that starts it). A script of
/// definitions only is complete when the connection closes (or goes quiet, see
/// [`crate::ur5e::script`]); [`is_closed`] tells that case.
pub fn is_complete(text: &str) -> bool {
    matches!(shape(text), Some((true, false)))
}

/// Whether every block in `text` is closed at a line break (the script may still be followed
/// by more top-level statements).
pub fn is_closed(text: &str) -> bool {
    shape(text).is_some()
}

/// `Some((has a top-level statement, the last top-level item is a definition))` when `text`
/// lexes, ends at a line break and closes every block; `None` otherwise.
fn shape(text: &str) -> Option<(bool, bool)> {
    if !text.ends_with('\n') {
        return None;
    }
    let tokens = lexer::lex(text).ok()?;
    let mut depth: i64 = 0;
    let mut at_start = true;
    let mut any = false;
    let mut last_is_def = false;
    for t in &tokens {
        if t.kind == lexer::Tok::Newline {
            at_start = true;
            continue;
        }
        if !at_start {
            continue;
        }
        at_start = false;
        let opens = ["def", "thread", "while", "if"]
            .iter()
            .any(|w| t.kind.is_word(w));
        if t.kind.is_word("end") {
            depth -= 1;
            if depth < 0 {
                return None;
            }
            continue;
        }
        if depth == 0 {
            last_is_def = t.kind.is_word("def") || t.kind.is_word("thread");
            any |= !last_is_def;
        }
        if opens {
            depth += 1;
        }
    }
    (depth == 0 && !tokens.is_empty()).then_some((any, last_is_def))
}
