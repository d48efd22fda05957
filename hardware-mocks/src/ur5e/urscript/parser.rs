//! Tokens → syntax tree ([`parse`]): a recursive-descent parser for the statement and
//! expression forms listed in the module docs of [`super`].
//!
//! Operator precedence, lowest first: `or`, `and`, `not`, comparisons (`== != < <= > >=`,
//! not chained), `+ -`, `* / %`, unary `-`, then indexing and calls. Anything else (`for`,
//! `sec`, `def` with default parameter values, `+=`, …) is a syntax error naming its line.

use super::ScriptError;
use super::ast::{BinOp, Expr, Scope, Stmt, StmtKind, UnOp};
use super::lexer::{Tok, Token};

/// Words that cannot be variable or function names.
const KEYWORDS: &[&str] = &[
    "def",
    "thread",
    "while",
    "if",
    "elif",
    "else",
    "end",
    "global",
    "local",
    "return",
    "halt",
    "run",
    "kill",
    "join",
    "and",
    "or",
    "not",
    "True",
    "False",
    "enter_critical",
    "exit_critical",
    "break",
    "continue",
];

/// Nesting depth of blocks and expressions beyond which a script is refused (a stack guard:
/// the parser recurses once per level).
const MAX_DEPTH: usize = 64;

/// Parses a whole script into its top-level statements.
pub fn parse(tokens: &[Token]) -> Result<Vec<Stmt>, ScriptError> {
    let mut p = Parser {
        toks: tokens,
        pos: 0,
        depth: 0,
    };
    let (body, stop) = p.block(&[])?;
    match stop {
        None => Ok(body),
        Some(word) => Err(p.err(format!("`{word}` without an open block"))),
    }
}

struct Parser<'a> {
    toks: &'a [Token],
    pos: usize,
    depth: usize,
}

impl Parser<'_> {
    fn peek(&self) -> Option<&Tok> {
        self.toks.get(self.pos).map(|t| &t.kind)
    }
    fn peek_at(&self, n: usize) -> Option<&Tok> {
        self.toks.get(self.pos + n).map(|t| &t.kind)
    }
    fn line(&self) -> u32 {
        self.toks
            .get(self.pos)
            .or(self.toks.last())
            .map_or(1, |t| t.line)
    }
    fn err(&self, msg: String) -> ScriptError {
        ScriptError::Syntax {
            line: self.line(),
            msg,
        }
    }
    fn next(&mut self) -> Option<Tok> {
        let t = self.toks.get(self.pos).map(|t| t.kind.clone());
        self.pos += 1;
        t
    }
    fn eat(&mut self, t: &Tok) -> bool {
        if self.peek() == Some(t) {
            self.pos += 1;
            true
        } else {
            false
        }
    }
    fn expect(&mut self, t: &Tok, what: &str) -> Result<(), ScriptError> {
        if self.eat(t) {
            Ok(())
        } else {
            Err(self.err(format!("expected {what}, found {}", self.found())))
        }
    }
    fn found(&self) -> String {
        match self.peek() {
            None => "the end of the script".into(),
            Some(Tok::Newline) => "the end of the line".into(),
            Some(t) => format!("{t:?}"),
        }
    }
    fn end_of_statement(&mut self) -> Result<(), ScriptError> {
        if self.peek().is_none() || self.eat(&Tok::Newline) {
            Ok(())
        } else {
            Err(self.err(format!(
                "expected the end of the statement, found {}",
                self.found()
            )))
        }
    }
    fn name(&mut self, what: &str) -> Result<String, ScriptError> {
        match self.peek() {
            Some(Tok::Ident(w)) if !KEYWORDS.contains(&w.as_str()) => {
                let w = w.clone();
                self.pos += 1;
                Ok(w)
            }
            _ => Err(self.err(format!("expected {what}, found {}", self.found()))),
        }
    }
    fn enter(&mut self) -> Result<(), ScriptError> {
        self.depth += 1;
        if self.depth > MAX_DEPTH {
            Err(self.err(format!("nested more than {MAX_DEPTH} levels deep")))
        } else {
            Ok(())
        }
    }

    /// Statements up to one of the `stops` words at the start of a statement (consumed and
    /// returned) or the end of the tokens (`None`).
    fn block(&mut self, stops: &[&str]) -> Result<(Vec<Stmt>, Option<String>), ScriptError> {
        self.enter()?;
        let mut body = Vec::new();
        let stop = loop {
            match self.peek() {
                None => break None,
                Some(Tok::Newline) => self.pos += 1,
                Some(Tok::Ident(w)) if stops.contains(&w.as_str()) || w == "end" => {
                    let w = w.clone();
                    if !stops.contains(&w.as_str()) {
                        return Err(self.err(format!("`{w}` without an open block")));
                    }
                    self.pos += 1;
                    break Some(w);
                }
                Some(Tok::Ident(w)) if w == "elif" || w == "else" => {
                    return Err(self.err(format!("`{w}` without an `if`")));
                }
                Some(_) => body.push(self.statement()?),
            }
        };
        self.depth -= 1;
        Ok((body, stop))
    }

    /// A block body closed by `end` (the opening line's `:` and line break already read).
    fn body_to_end(&mut self, opener: &str, line: u32) -> Result<Vec<Stmt>, ScriptError> {
        match self.block(&["end"])? {
            (body, Some(_)) => Ok(body),
            (_, None) => Err(ScriptError::Syntax {
                line,
                msg: format!("`{opener}` block never closed with `end`"),
            }),
        }
    }

    fn colon_newline(&mut self) -> Result<(), ScriptError> {
        self.expect(&Tok::Colon, "`:`")?;
        self.end_of_statement()
    }

    fn statement(&mut self) -> Result<Stmt, ScriptError> {
        let line = self.line();
        let word = match self.peek() {
            Some(Tok::Ident(w)) => Some(w.clone()),
            _ => None,
        };
        let simple = |kind| Stmt { line, kind };
        let kind = match word.as_deref() {
            Some("def") => {
                self.pos += 1;
                let name = self.name("a function name")?;
                self.expect(&Tok::LParen, "`(`")?;
                let mut params = Vec::new();
                if !self.eat(&Tok::RParen) {
                    loop {
                        params.push(self.name("a parameter name")?);
                        if self.eat(&Tok::RParen) {
                            break;
                        }
                        self.expect(&Tok::Comma, "`,` or `)`")?;
                    }
                }
                self.colon_newline()?;
                let body = self.body_to_end("def", line)?;
                StmtKind::Def { name, params, body }
            }
            Some("thread") => {
                self.pos += 1;
                let name = self.name("a thread name")?;
                self.expect(&Tok::LParen, "`(`")?;
                self.expect(&Tok::RParen, "`)` (threads take no parameters)")?;
                self.colon_newline()?;
                let body = self.body_to_end("thread", line)?;
                StmtKind::Thread { name, body }
            }
            Some("while") => {
                self.pos += 1;
                let cond = self.expr()?;
                self.colon_newline()?;
                let body = self.body_to_end("while", line)?;
                StmtKind::While { cond, body }
            }
            Some("if") => {
                self.pos += 1;
                let mut arms = Vec::new();
                let mut otherwise = Vec::new();
                let mut cond = self.expr()?;
                loop {
                    self.colon_newline()?;
                    let (body, stop) = self.block(&["elif", "else", "end"])?;
                    arms.push((cond, body));
                    match stop.as_deref() {
                        Some("elif") => cond = self.expr()?,
                        Some("else") => {
                            self.colon_newline()?;
                            otherwise = self.body_to_end("else", line)?;
                            break;
                        }
                        Some(_) => break,
                        None => {
                            return Err(ScriptError::Syntax {
                                line,
                                msg: "`if` block never closed with `end`".into(),
                            });
                        }
                    }
                }
                StmtKind::If { arms, otherwise }
            }
            Some(q @ ("global" | "local")) => {
                let scope = if q == "global" {
                    Scope::Global
                } else {
                    Scope::Local
                };
                self.pos += 1;
                let name = self.name("a variable name")?;
                self.expect(&Tok::Assign, "`=` (a declaration needs a value)")?;
                let value = self.expr()?;
                StmtKind::Assign {
                    scope,
                    name,
                    index: None,
                    value,
                }
            }
            Some("return") => {
                self.pos += 1;
                if matches!(self.peek(), None | Some(Tok::Newline)) {
                    StmtKind::Return(None)
                } else {
                    StmtKind::Return(Some(self.expr()?))
                }
            }
            Some(w @ ("halt" | "enter_critical" | "exit_critical" | "break" | "continue")) => {
                let k = match w {
                    "halt" => StmtKind::Halt,
                    "enter_critical" => StmtKind::EnterCritical,
                    "exit_critical" => StmtKind::ExitCritical,
                    "break" => StmtKind::Break,
                    _ => StmtKind::Continue,
                };
                self.pos += 1;
                k
            }
            Some(w @ ("kill" | "join")) => {
                let join = w == "join";
                self.pos += 1;
                let e = self.expr()?;
                if join {
                    StmtKind::Join(e)
                } else {
                    StmtKind::Kill(e)
                }
            }
            Some(w) if KEYWORDS.contains(&w) && !matches!(w, "run" | "not" | "True" | "False") => {
                return Err(self.err(format!("`{w}` cannot start a statement")));
            }
            _ => {
                let e = self.expr()?;
                if self.eat(&Tok::Assign) {
                    let value = self.expr()?;
                    match e {
                        Expr::Var(name) => StmtKind::Assign {
                            scope: Scope::Free,
                            name,
                            index: None,
                            value,
                        },
                        Expr::Index(target, i) => match *target {
                            Expr::Var(name) => StmtKind::Assign {
                                scope: Scope::Free,
                                name,
                                index: Some(*i),
                                value,
                            },
                            _ => return Err(self.err("cannot assign to this expression".into())),
                        },
                        _ => return Err(self.err("cannot assign to this expression".into())),
                    }
                } else {
                    match e {
                        Expr::Call { .. } | Expr::Run(_) => StmtKind::Expr(e),
                        _ => {
                            return Err(ScriptError::Syntax {
                                line,
                                msg: "unsupported statement (an expression that is not a call)"
                                    .into(),
                            });
                        }
                    }
                }
            }
        };
        if !matches!(
            kind,
            StmtKind::Def { .. }
                | StmtKind::Thread { .. }
                | StmtKind::While { .. }
                | StmtKind::If { .. }
        ) {
            self.end_of_statement()?;
        }
        Ok(simple(kind))
    }

    fn expr(&mut self) -> Result<Expr, ScriptError> {
        self.enter()?;
        let e = self.or_expr();
        self.depth -= 1;
        e
    }

    fn or_expr(&mut self) -> Result<Expr, ScriptError> {
        let mut l = self.and_expr()?;
        while self.peek().is_some_and(|t| t.is_word("or")) {
            self.pos += 1;
            l = Expr::Or(Box::new(l), Box::new(self.and_expr()?));
        }
        Ok(l)
    }

    fn and_expr(&mut self) -> Result<Expr, ScriptError> {
        let mut l = self.not_expr()?;
        while self.peek().is_some_and(|t| t.is_word("and")) {
            self.pos += 1;
            l = Expr::And(Box::new(l), Box::new(self.not_expr()?));
        }
        Ok(l)
    }

    fn not_expr(&mut self) -> Result<Expr, ScriptError> {
        if self.peek().is_some_and(|t| t.is_word("not")) {
            self.pos += 1;
            self.enter()?;
            let e = self.not_expr();
            self.depth -= 1;
            return Ok(Expr::Unary(UnOp::Not, Box::new(e?)));
        }
        self.comparison()
    }

    fn comparison(&mut self) -> Result<Expr, ScriptError> {
        let l = self.sum()?;
        let op = match self.peek() {
            Some(Tok::Eq) => BinOp::Eq,
            Some(Tok::Ne) => BinOp::Ne,
            Some(Tok::Lt) => BinOp::Lt,
            Some(Tok::Le) => BinOp::Le,
            Some(Tok::Gt) => BinOp::Gt,
            Some(Tok::Ge) => BinOp::Ge,
            _ => return Ok(l),
        };
        self.pos += 1;
        Ok(Expr::Binary(op, Box::new(l), Box::new(self.sum()?)))
    }

    fn sum(&mut self) -> Result<Expr, ScriptError> {
        let mut l = self.product()?;
        loop {
            let op = match self.peek() {
                Some(Tok::Plus) => BinOp::Add,
                Some(Tok::Minus) => BinOp::Sub,
                _ => return Ok(l),
            };
            self.pos += 1;
            l = Expr::Binary(op, Box::new(l), Box::new(self.product()?));
        }
    }

    fn product(&mut self) -> Result<Expr, ScriptError> {
        let mut l = self.unary()?;
        loop {
            let op = match self.peek() {
                Some(Tok::Star) => BinOp::Mul,
                Some(Tok::Slash) => BinOp::Div,
                Some(Tok::Percent) => BinOp::Mod,
                _ => return Ok(l),
            };
            self.pos += 1;
            l = Expr::Binary(op, Box::new(l), Box::new(self.unary()?));
        }
    }

    fn unary(&mut self) -> Result<Expr, ScriptError> {
        if self.eat(&Tok::Minus) {
            self.enter()?;
            let e = self.unary();
            self.depth -= 1;
            return Ok(match e? {
                // Fold literals so `-2147483648`-style limits and `-1.5` stay literals.
                Expr::Int(i) => Expr::Int(i.wrapping_neg()),
                Expr::Float(f) => Expr::Float(-f),
                e => Expr::Unary(UnOp::Neg, Box::new(e)),
            });
        }
        if self.eat(&Tok::Plus) {
            return self.unary();
        }
        self.postfix()
    }

    fn postfix(&mut self) -> Result<Expr, ScriptError> {
        let mut e = self.primary()?;
        while self.eat(&Tok::LBracket) {
            let i = self.expr()?;
            self.expect(&Tok::RBracket, "`]`")?;
            e = Expr::Index(Box::new(e), Box::new(i));
        }
        Ok(e)
    }

    fn items(&mut self, close: &Tok) -> Result<Vec<Expr>, ScriptError> {
        let mut items = Vec::new();
        if self.eat(close) {
            return Ok(items);
        }
        loop {
            items.push(self.expr()?);
            if self.eat(close) {
                return Ok(items);
            }
            self.expect(&Tok::Comma, "`,`")?;
        }
    }

    fn primary(&mut self) -> Result<Expr, ScriptError> {
        match self.next() {
            Some(Tok::Int(i)) => Ok(Expr::Int(i)),
            Some(Tok::Float(f)) => Ok(Expr::Float(f)),
            Some(Tok::Str(s)) => Ok(Expr::Str(s)),
            Some(Tok::LParen) => {
                let e = self.expr()?;
                self.expect(&Tok::RParen, "`)`")?;
                Ok(e)
            }
            Some(Tok::LBracket) => Ok(Expr::List(self.items(&Tok::RBracket)?)),
            Some(Tok::PoseOpen) => {
                let items = self.items(&Tok::RBracket)?;
                if items.len() != 6 {
                    return Err(self.err(format!(
                        "a pose literal has 6 elements, this one {}",
                        items.len()
                    )));
                }
                Ok(Expr::Pose(items))
            }
            Some(Tok::Ident(w)) if w == "True" || w == "False" => Ok(Expr::Bool(w == "True")),
            Some(Tok::Ident(w)) if w == "run" => {
                let name = self.name("a thread name after `run`")?;
                self.expect(&Tok::LParen, "`(`")?;
                self.expect(&Tok::RParen, "`)` (threads take no arguments)")?;
                Ok(Expr::Run(name))
            }
            Some(Tok::Ident(w)) if !KEYWORDS.contains(&w.as_str()) => {
                if !self.eat(&Tok::LParen) {
                    return Ok(Expr::Var(w));
                }
                let mut args = Vec::new();
                let mut kwargs: Vec<(String, Expr)> = Vec::new();
                if !self.eat(&Tok::RParen) {
                    loop {
                        let keyword = match (self.peek(), self.peek_at(1)) {
                            (Some(Tok::Ident(k)), Some(Tok::Assign)) => Some(k.clone()),
                            _ => None,
                        };
                        if let Some(k) = keyword {
                            self.pos += 2;
                            if kwargs.iter().any(|(n, _)| *n == k) {
                                return Err(self.err(format!("argument `{k}` given twice")));
                            }
                            kwargs.push((k, self.expr()?));
                        } else if !kwargs.is_empty() {
                            return Err(
                                self.err("a positional argument after a keyword argument".into())
                            );
                        } else {
                            args.push(self.expr()?);
                        }
                        if self.eat(&Tok::RParen) {
                            break;
                        }
                        self.expect(&Tok::Comma, "`,` or `)`")?;
                    }
                }
                Ok(Expr::Call {
                    name: w,
                    args,
                    kwargs,
                })
            }
            Some(Tok::Ident(w)) => Err(ScriptError::Syntax {
                line: self.toks[self.pos - 1].line,
                msg: format!("unexpected `{w}`"),
            }),
            _ => {
                self.pos = self.pos.saturating_sub(1);
                Err(self.err(format!("expected an expression, found {}", self.found())))
            }
        }
    }
}
