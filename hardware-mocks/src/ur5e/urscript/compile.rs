//! Syntax tree → a flat list of [`Op`]s, one list for the whole script.
//!
//! A flat instruction list with an explicit program counter and value stack per thread is what
//! lets a thread stop in the middle of anything (a `movel` inside a function called from a
//! loop) at the end of a controller cycle and go on from the same point in the next one.
//!
//! Every `def` and `thread`, wherever it stands, is known by name before anything runs (so the
//! rig's program may `run` a thread defined inside its `def`). A name is one function or thread
//! only, and cannot be a built-in's. Calls are resolved here: a call to a name that is neither
//! a built-in ([`super::builtins`]) nor defined in the script, a wrong argument count for a
//! user function, `break` outside a loop, and so on are errors before the program starts, as
//! they are when a real controller compiles a script.
//!
//! What runs: the script's top-level statements other than definitions (the rig's program ends
//! with the call `transforce_rig()`); a script that has only definitions runs its first `def`,
//! as a controller runs a `def prog(): … end` sent to it.

use std::collections::HashMap;

use super::ScriptError;
use super::ast::{BinOp, Expr, Scope, Stmt, StmtKind, UnOp};
use super::builtins::{self, Builtin};
use super::value::Value;

#[derive(Debug, Clone, PartialEq)]
pub enum Op {
    /// A statement on this source line starts (counted against the per-cycle budget).
    Line(u32),
    Const(Value),
    Load(String),
    Store(String, Scope),
    /// Stack: index, value.
    StoreIndex(String, Scope),
    /// Stack: container, index.
    Index,
    MakeList(usize),
    MakePose,
    Unary(UnOp),
    Binary(BinOp),
    Jump(usize),
    /// Pops a bool; jumps when it is False.
    JumpIfFalse(usize),
    /// `and`: a False left side stays on the stack as the result and jumps past the right.
    AndJump(usize),
    /// `or`: a True left side stays on the stack as the result and jumps past the right.
    OrJump(usize),
    /// The right side of `and`/`or` must be a bool too.
    CheckBool,
    CallBuiltin {
        f: Builtin,
        positional: usize,
        keywords: Vec<String>,
    },
    CallUser {
        func: usize,
        nargs: usize,
    },
    /// Pops the return value, leaves the function (or ends the thread).
    Return,
    Pop,
    /// Starts thread `func`; pushes its handle.
    Run(usize),
    Kill,
    Join,
    EnterCritical,
    ExitCritical,
    Halt,
    /// End of the main program.
    End,
}

/// A `def` or `thread`.
#[derive(Debug, Clone, PartialEq)]
pub struct Func {
    pub name: String,
    pub params: Vec<String>,
    pub entry: usize,
    pub is_thread: bool,
    pub line: u32,
}

/// A compiled script: the main program starts at op 0.
#[derive(Debug, Clone, PartialEq)]
pub struct Code {
    pub ops: Vec<Op>,
    pub funcs: Vec<Func>,
}

struct Compiler<'a> {
    ops: Vec<Op>,
    funcs: Vec<Func>,
    by_name: HashMap<String, usize>,
    bodies: Vec<&'a [Stmt]>,
    /// Per open loop: the op to `continue` to and the jumps that `break` must patch.
    loops: Vec<(usize, Vec<usize>)>,
}

fn syntax(line: u32, msg: String) -> ScriptError {
    ScriptError::Syntax { line, msg }
}

/// Compiles the top-level statements of a script.
pub fn compile(top: &[Stmt]) -> Result<Code, ScriptError> {
    let mut c = Compiler {
        ops: Vec::new(),
        funcs: Vec::new(),
        by_name: HashMap::new(),
        bodies: Vec::new(),
        loops: Vec::new(),
    };
    c.declare(top)?;
    let runs_something = top
        .iter()
        .any(|s| !matches!(s.kind, StmtKind::Def { .. } | StmtKind::Thread { .. }));
    if runs_something {
        c.block(top)?;
    } else {
        let Some(first) = c.funcs.iter().position(|f| !f.is_thread) else {
            return Err(syntax(1, "the script defines no program to run".into()));
        };
        let f = &c.funcs[first];
        if !f.params.is_empty() {
            return Err(syntax(
                f.line,
                format!("program `{}` takes parameters", f.name),
            ));
        }
        let line = f.line;
        c.ops.push(Op::Line(line));
        c.ops.push(Op::CallUser {
            func: first,
            nargs: 0,
        });
        c.ops.push(Op::Pop);
    }
    c.ops.push(Op::End);
    for i in 0..c.funcs.len() {
        c.funcs[i].entry = c.ops.len();
        let body = c.bodies[i];
        c.block(body)?;
        c.ops.push(Op::Const(Value::None));
        c.ops.push(Op::Return);
    }
    Ok(Code {
        ops: c.ops,
        funcs: c.funcs,
    })
}

impl<'a> Compiler<'a> {
    /// Registers every `def` and `thread` in `stmts`, nested ones included.
    fn declare(&mut self, stmts: &'a [Stmt]) -> Result<(), ScriptError> {
        for s in stmts {
            let (name, params, body, is_thread) = match &s.kind {
                StmtKind::Def { name, params, body } => (name, params.clone(), body, false),
                StmtKind::Thread { name, body } => (name, Vec::new(), body, true),
                StmtKind::If { arms, otherwise } => {
                    for (_, b) in arms {
                        self.declare(b)?;
                    }
                    self.declare(otherwise)?;
                    continue;
                }
                StmtKind::While { body, .. } => {
                    self.declare(body)?;
                    continue;
                }
                _ => continue,
            };
            if builtins::lookup(name).is_some() {
                return Err(syntax(s.line, format!("`{name}` is a built-in function")));
            }
            if self.by_name.contains_key(name) {
                return Err(syntax(s.line, format!("`{name}` is defined twice")));
            }
            self.by_name.insert(name.clone(), self.funcs.len());
            self.funcs.push(Func {
                name: name.clone(),
                params,
                entry: 0,
                is_thread,
                line: s.line,
            });
            self.bodies.push(body);
            self.declare(body)?;
        }
        Ok(())
    }

    fn block(&mut self, stmts: &[Stmt]) -> Result<(), ScriptError> {
        for s in stmts {
            self.stmt(s)?;
        }
        Ok(())
    }

    fn here(&self) -> usize {
        self.ops.len()
    }

    fn patch(&mut self, at: usize, to: usize) {
        match &mut self.ops[at] {
            Op::Jump(t) | Op::JumpIfFalse(t) | Op::AndJump(t) | Op::OrJump(t) => *t = to,
            other => unreachable!("patching {other:?}"),
        }
    }

    fn stmt(&mut self, s: &Stmt) -> Result<(), ScriptError> {
        let line = s.line;
        match &s.kind {
            StmtKind::Def { .. } | StmtKind::Thread { .. } => return Ok(()),
            StmtKind::While { .. } => {}
            _ => self.ops.push(Op::Line(line)),
        }
        match &s.kind {
            StmtKind::Def { .. } | StmtKind::Thread { .. } => {}
            StmtKind::Expr(e) => {
                self.expr(e, line)?;
                self.ops.push(Op::Pop);
            }
            StmtKind::Assign {
                scope,
                name,
                index,
                value,
            } => {
                if let Some(i) = index {
                    self.expr(i, line)?;
                    self.expr(value, line)?;
                    self.ops.push(Op::StoreIndex(name.clone(), *scope));
                } else {
                    self.expr(value, line)?;
                    self.ops.push(Op::Store(name.clone(), *scope));
                }
            }
            StmtKind::If { arms, otherwise } => {
                let mut ends = Vec::new();
                for (cond, body) in arms {
                    self.expr(cond, line)?;
                    let skip = self.here();
                    self.ops.push(Op::JumpIfFalse(0));
                    self.block(body)?;
                    ends.push(self.here());
                    self.ops.push(Op::Jump(0));
                    let next = self.here();
                    self.patch(skip, next);
                }
                self.block(otherwise)?;
                let end = self.here();
                for j in ends {
                    self.patch(j, end);
                }
            }
            StmtKind::While { cond, body } => {
                let head = self.here();
                self.ops.push(Op::Line(line));
                self.expr(cond, line)?;
                let exit = self.here();
                self.ops.push(Op::JumpIfFalse(0));
                self.loops.push((head, Vec::new()));
                self.block(body)?;
                self.ops.push(Op::Jump(head));
                let end = self.here();
                self.patch(exit, end);
                let (_, breaks) = self.loops.pop().expect("pushed above");
                for b in breaks {
                    self.patch(b, end);
                }
            }
            StmtKind::Return(e) => {
                match e {
                    Some(e) => self.expr(e, line)?,
                    None => self.ops.push(Op::Const(Value::None)),
                }
                self.ops.push(Op::Return);
            }
            StmtKind::Halt => self.ops.push(Op::Halt),
            StmtKind::Kill(e) => {
                self.expr(e, line)?;
                self.ops.push(Op::Kill);
            }
            StmtKind::Join(e) => {
                self.expr(e, line)?;
                self.ops.push(Op::Join);
            }
            StmtKind::EnterCritical => self.ops.push(Op::EnterCritical),
            StmtKind::ExitCritical => self.ops.push(Op::ExitCritical),
            StmtKind::Break | StmtKind::Continue => {
                let brk = matches!(s.kind, StmtKind::Break);
                let at = self.here();
                let Some((head, breaks)) = self.loops.last_mut() else {
                    let w = if brk { "break" } else { "continue" };
                    return Err(syntax(line, format!("`{w}` outside a loop")));
                };
                if brk {
                    breaks.push(at);
                    self.ops.push(Op::Jump(0));
                } else {
                    let head = *head;
                    self.ops.push(Op::Jump(head));
                }
            }
        }
        Ok(())
    }

    fn expr(&mut self, e: &Expr, line: u32) -> Result<(), ScriptError> {
        match e {
            Expr::Int(i) => self.ops.push(Op::Const(Value::Int(*i))),
            Expr::Float(f) => self.ops.push(Op::Const(Value::Float(*f))),
            Expr::Bool(b) => self.ops.push(Op::Const(Value::Bool(*b))),
            Expr::Str(s) => self.ops.push(Op::Const(Value::Str(s.clone()))),
            Expr::Var(n) => self.ops.push(Op::Load(n.clone())),
            Expr::List(items) => {
                for i in items {
                    self.expr(i, line)?;
                }
                self.ops.push(Op::MakeList(items.len()));
            }
            Expr::Pose(items) => {
                for i in items {
                    self.expr(i, line)?;
                }
                self.ops.push(Op::MakePose);
            }
            Expr::Index(a, i) => {
                self.expr(a, line)?;
                self.expr(i, line)?;
                self.ops.push(Op::Index);
            }
            Expr::Unary(op, a) => {
                self.expr(a, line)?;
                self.ops.push(Op::Unary(*op));
            }
            Expr::Binary(op, a, b) => {
                self.expr(a, line)?;
                self.expr(b, line)?;
                self.ops.push(Op::Binary(*op));
            }
            Expr::And(a, b) | Expr::Or(a, b) => {
                self.expr(a, line)?;
                let j = self.here();
                self.ops.push(if matches!(e, Expr::And(..)) {
                    Op::AndJump(0)
                } else {
                    Op::OrJump(0)
                });
                self.expr(b, line)?;
                self.ops.push(Op::CheckBool);
                let end = self.here();
                self.patch(j, end);
            }
            Expr::Run(name) => match self.by_name.get(name) {
                Some(&f) if self.funcs[f].is_thread => self.ops.push(Op::Run(f)),
                Some(_) => return Err(syntax(line, format!("`{name}` is not a thread"))),
                None => return Err(syntax(line, format!("unknown thread `{name}`"))),
            },
            Expr::Call { name, args, kwargs } => {
                if let Some(&f) = self.by_name.get(name) {
                    let func = &self.funcs[f];
                    if func.is_thread {
                        return Err(syntax(
                            line,
                            format!("`{name}` is a thread: start it with `run {name}()`"),
                        ));
                    }
                    if !kwargs.is_empty() {
                        return Err(syntax(
                            line,
                            format!(
                                "keyword arguments to user function `{name}` are not supported"
                            ),
                        ));
                    }
                    if args.len() != func.params.len() {
                        return Err(syntax(
                            line,
                            format!(
                                "`{name}` takes {} argument(s), {} given",
                                func.params.len(),
                                args.len()
                            ),
                        ));
                    }
                    for a in args {
                        self.expr(a, line)?;
                    }
                    self.ops.push(Op::CallUser {
                        func: f,
                        nargs: args.len(),
                    });
                } else if let Some(f) = builtins::lookup(name) {
                    builtins::check_call(f, args.len(), kwargs.iter().map(|(k, _)| k.as_str()))
                        .map_err(|m| syntax(line, m))?;
                    for a in args {
                        self.expr(a, line)?;
                    }
                    for (_, a) in kwargs {
                        self.expr(a, line)?;
                    }
                    self.ops.push(Op::CallBuiltin {
                        f,
                        positional: args.len(),
                        keywords: kwargs.iter().map(|(k, _)| k.clone()).collect(),
                    });
                } else {
                    return Err(syntax(line, format!("unknown function `{name}`")));
                }
            }
        }
        Ok(())
    }
}
