//! Runs compiled URScript ([`Code`]), one controller cycle per [`Interpreter::step`].
//!
//! # Scheduling (URScript manual, "Threads", "Thread scheduling")
//!
//! The main program and every thread started with `run` are threads. Each cycle they run in a
//! fixed order, main first, then the others in the order they were started; a thread started
//! during a cycle gets its first turn in that same cycle, after the threads before it. A thread
//! runs until it blocks, so a sequence of statements without a blocking call is never
//! interleaved with another thread:
//!
//! - `sync()` ends the thread's cycle;
//! - `movel` blocks until that motion has ended (reached its target, or was stopped, or
//!   another `movel` replaced it);
//! - `stopl(a)` blocks until the arm is at rest;
//! - `sleep(t)` blocks until `t` seconds of controller time have passed;
//! - `join h` blocks until thread `h` has ended.
//!
//! `enter_critical` … `exit_critical` therefore only has to forbid blocking inside it, which
//! is a runtime error here. A thread that executes more than [`STATEMENT_BUDGET`] statements in
//! one cycle without blocking is a runtime error (a real controller flags such a thread as a
//! runaway and stops the program). `kill h` removes thread `h` at once: a `movel` it was
//! waiting for is not stopped (the arm keeps following that motion until the next motion
//! command, see [`Robot::movel`] and [`Robot::stopl`]). The program ends when the main thread
//! ends, or at `halt`.
//!
//! # Variables (URScript manual, "Scoping rules")
//!
//! Top-level statements work on globals. Inside a function or thread, `local x = …` binds a
//! local, `global x = …` a global, and a plain `x = …` the global `x` if one exists, else a
//! local. Reading a name looks at the locals, then the globals.

use std::collections::HashMap;
use std::sync::Arc;

use super::ast::Scope;
use super::builtins::{self, Flow, Wait};
use super::compile::{Code, Op};
use super::value::{self, Value};
use super::{Robot, RuntimeError};

/// Statements one thread may execute in one cycle without blocking.
pub const STATEMENT_BUDGET: u32 = 10_000;
/// Nested user-function calls per thread.
pub const MAX_CALL_DEPTH: usize = 200;
/// Threads alive at once (main included).
pub const MAX_THREADS: usize = 64;
/// Values in one list, nested lists' values included.
pub const MAX_LIST_VALUES: usize = 10_000;

/// How many values `v` holds, counting nested lists' values, stopping past `limit`.
fn weight(v: &Value, limit: usize) -> usize {
    match v {
        Value::List(items) => {
            let mut n = 1;
            for i in items {
                n += weight(i, limit);
                if n > limit {
                    break;
                }
            }
            n
        }
        _ => 1,
    }
}

#[derive(Debug, Clone)]
struct Frame {
    ret_pc: usize,
    /// `None` for the top level, whose variables are the globals.
    locals: Option<HashMap<String, Value>>,
}

#[derive(Debug, Clone)]
struct Thread {
    id: u32,
    name: String,
    pc: usize,
    stack: Vec<Value>,
    frames: Vec<Frame>,
    wait: Wait,
    line: u32,
    critical: bool,
    alive: bool,
}

/// How a cycle ended for the program.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Outcome {
    /// Still running.
    Running,
    /// The main program ended.
    Finished,
    /// `halt`.
    Halted,
}

/// One running program: its globals and threads.
#[derive(Debug, Clone)]
pub struct Interpreter {
    code: Arc<Code>,
    globals: HashMap<String, Value>,
    threads: Vec<Thread>,
    next_id: u32,
}

enum Exit {
    Blocked,
    Finished,
    Halt,
}

impl Interpreter {
    /// A program about to run its first statement.
    pub fn new(code: Arc<Code>) -> Self {
        Self {
            code,
            globals: HashMap::new(),
            threads: vec![Thread {
                id: 0,
                name: "main".into(),
                pc: 0,
                stack: Vec::new(),
                frames: vec![Frame {
                    ret_pc: usize::MAX,
                    locals: None,
                }],
                wait: Wait::None,
                line: 0,
                critical: false,
                alive: true,
            }],
            next_id: 1,
        }
    }

    /// A global's value (for tests and diagnostics).
    pub fn global(&self, name: &str) -> Option<&Value> {
        self.globals.get(name)
    }

    /// Names of the live threads, main first.
    pub fn thread_names(&self) -> Vec<String> {
        self.threads
            .iter()
            .filter(|t| t.alive)
            .map(|t| t.name.clone())
            .collect()
    }

    /// Runs one controller cycle.
    pub fn step(&mut self, robot: &mut dyn Robot) -> Result<Outcome, RuntimeError> {
        let mut i = 0;
        let result = loop {
            if i >= self.threads.len() {
                break Ok(Outcome::Running);
            }
            if !self.threads[i].alive || !self.ready(i, robot) {
                i += 1;
                continue;
            }
            self.threads[i].wait = Wait::None;
            let mut th = std::mem::replace(&mut self.threads[i], placeholder());
            let exit = self.run(&mut th, robot);
            let main = th.id == 0;
            self.threads[i] = th;
            match exit {
                Err(e) => break Err(e),
                Ok(Exit::Halt) => break Ok(Outcome::Halted),
                Ok(Exit::Finished) if main => break Ok(Outcome::Finished),
                Ok(Exit::Finished) => self.threads[i].alive = false,
                Ok(Exit::Blocked) => {}
            }
            i += 1;
        };
        self.threads.retain(|t| t.alive);
        result
    }

    fn ready(&self, i: usize, robot: &dyn Robot) -> bool {
        match self.threads[i].wait {
            Wait::None | Wait::NextCycle => true,
            Wait::Motion(id) => !robot.motion_running(id),
            Wait::Rest => robot.at_rest(),
            Wait::Until(t) => robot.now_ns() >= t,
            Wait::Join(id) => !self.threads.iter().any(|t| t.alive && t.id == id),
        }
    }

    fn load(&self, th: &Thread, name: &str) -> Option<Value> {
        th.frames
            .last()
            .and_then(|f| f.locals.as_ref())
            .and_then(|l| l.get(name))
            .or_else(|| self.globals.get(name))
            .cloned()
    }

    fn store(&mut self, th: &mut Thread, name: &str, scope: Scope, v: Value) {
        let locals = th.frames.last_mut().and_then(|f| f.locals.as_mut());
        match (scope, locals) {
            (Scope::Global, _) | (_, None) => {
                self.globals.insert(name.to_owned(), v);
            }
            (Scope::Local, Some(l)) => {
                l.insert(name.to_owned(), v);
            }
            (Scope::Free, Some(l)) => {
                if !l.contains_key(name) && self.globals.contains_key(name) {
                    self.globals.insert(name.to_owned(), v);
                } else {
                    l.insert(name.to_owned(), v);
                }
            }
        }
    }

    /// Runs `th` until it blocks, ends or fails.
    fn run(&mut self, th: &mut Thread, robot: &mut dyn Robot) -> Result<Exit, RuntimeError> {
        let code = self.code.clone();
        let mut statements: u32 = 0;
        macro_rules! fail {
            ($($t:tt)*) => {
                return Err(RuntimeError { line: th.line, thread: th.name.clone(), msg: format!($($t)*) })
            };
        }
        macro_rules! pop {
            () => {
                match th.stack.pop() {
                    Some(v) => v,
                    None => fail!("internal error: value stack empty"),
                }
            };
        }
        loop {
            let Some(op) = code.ops.get(th.pc) else {
                fail!("internal error: no instruction at {}", th.pc);
            };
            th.pc += 1;
            match op {
                Op::Line(n) => {
                    th.line = *n;
                    statements += 1;
                    if statements > STATEMENT_BUDGET {
                        fail!(
                            "thread {} ran {STATEMENT_BUDGET} statements in one cycle without sync(); a real controller would flag this as a runaway loop",
                            th.name
                        );
                    }
                }
                Op::Const(v) => th.stack.push(v.clone()),
                Op::Load(name) => match self.load(th, name) {
                    Some(v) => th.stack.push(v),
                    None => fail!("variable `{name}` is not defined"),
                },
                Op::Store(name, scope) => {
                    let v = pop!();
                    self.store(th, name, *scope, v);
                }
                Op::StoreIndex(name, scope) => {
                    let v = pop!();
                    let i = pop!();
                    let Some(old) = self.load(th, name) else {
                        fail!("variable `{name}` is not defined");
                    };
                    match value::set_index(&old, &i, v) {
                        Ok(new) if weight(&new, MAX_LIST_VALUES) > MAX_LIST_VALUES => {
                            fail!("a list of more than {MAX_LIST_VALUES} values");
                        }
                        Ok(new) => self.store(th, name, *scope, new),
                        Err(m) => fail!("{m}"),
                    }
                }
                Op::Index => {
                    let i = pop!();
                    let a = pop!();
                    match value::index(&a, &i) {
                        Ok(v) => th.stack.push(v),
                        Err(m) => fail!("{m}"),
                    }
                }
                Op::MakeList(n) => {
                    let at = th.stack.len().saturating_sub(*n);
                    let items = th.stack.split_off(at);
                    let list = Value::List(items);
                    if weight(&list, MAX_LIST_VALUES) > MAX_LIST_VALUES {
                        fail!("a list of more than {MAX_LIST_VALUES} values");
                    }
                    th.stack.push(list);
                }
                Op::MakePose => {
                    let at = th.stack.len().saturating_sub(6);
                    let items = th.stack.split_off(at);
                    let mut arr = [0.0; 6];
                    for (slot, v) in arr.iter_mut().zip(&items) {
                        match v.as_f64() {
                            Some(x) => *slot = x,
                            None => fail!(
                                "type error: a pose element must be a number, got {}",
                                v.type_name()
                            ),
                        }
                    }
                    th.stack
                        .push(Value::Pose(rig_core::pose::Pose::from_array(arr)));
                }
                Op::Unary(op) => {
                    let a = pop!();
                    match value::unary(*op, &a) {
                        Ok(v) => th.stack.push(v),
                        Err(m) => fail!("{m}"),
                    }
                }
                Op::Binary(op) => {
                    let b = pop!();
                    let a = pop!();
                    match value::binary(*op, &a, &b) {
                        Ok(v) => th.stack.push(v),
                        Err(m) => fail!("{m}"),
                    }
                }
                Op::Jump(t) => th.pc = *t,
                Op::JumpIfFalse(t) => match pop!() {
                    Value::Bool(true) => {}
                    Value::Bool(false) => th.pc = *t,
                    v => fail!(
                        "type error: a condition must be a bool, got {}",
                        v.type_name()
                    ),
                },
                Op::AndJump(t) | Op::OrJump(t) => {
                    let jump_on = matches!(op, Op::OrJump(_));
                    match th.stack.last() {
                        Some(Value::Bool(b)) if *b == jump_on => th.pc = *t,
                        Some(Value::Bool(_)) => {
                            th.stack.pop();
                        }
                        Some(v) => {
                            fail!("type error: `and`/`or` need bools, got {}", v.type_name())
                        }
                        None => fail!("internal error: value stack empty"),
                    }
                }
                Op::CheckBool => {
                    if let Some(v) = th.stack.last().filter(|v| !matches!(v, Value::Bool(_))) {
                        fail!("type error: `and`/`or` need bools, got {}", v.type_name());
                    }
                }
                Op::CallBuiltin {
                    f,
                    positional,
                    keywords,
                } => {
                    let at = th.stack.len().saturating_sub(positional + keywords.len());
                    let args = th.stack.split_off(at);
                    match builtins::call(*f, args, keywords, robot) {
                        Ok(Flow::Value(v)) => th.stack.push(v),
                        Ok(Flow::Block(w)) => {
                            th.stack.push(Value::None);
                            if th.critical {
                                fail!(
                                    "{}() blocks inside enter_critical … exit_critical",
                                    builtins::name(*f)
                                );
                            }
                            th.wait = w;
                            return Ok(Exit::Blocked);
                        }
                        Err(m) => fail!("{}: {m}", builtins::name(*f)),
                    }
                }
                Op::CallUser { func, nargs } => {
                    let f = &code.funcs[*func];
                    if th.frames.len() >= MAX_CALL_DEPTH {
                        fail!(
                            "calls nested deeper than {MAX_CALL_DEPTH} (runaway recursion in `{}`)",
                            f.name
                        );
                    }
                    let at = th.stack.len().saturating_sub(*nargs);
                    let args = th.stack.split_off(at);
                    let locals = f.params.iter().cloned().zip(args).collect();
                    th.frames.push(Frame {
                        ret_pc: th.pc,
                        locals: Some(locals),
                    });
                    th.pc = f.entry;
                }
                Op::Return => {
                    let v = pop!();
                    let frame = th.frames.pop();
                    match frame {
                        Some(f) if f.ret_pc != usize::MAX && !th.frames.is_empty() => {
                            th.pc = f.ret_pc;
                            th.stack.push(v);
                        }
                        _ => return Ok(Exit::Finished),
                    }
                }
                Op::Pop => {
                    th.stack.pop();
                }
                Op::Run(func) => {
                    let f = &code.funcs[*func];
                    // This thread is out of the list while it runs: count it.
                    if self.threads.iter().filter(|t| t.alive).count() + 1 >= MAX_THREADS {
                        fail!("more than {MAX_THREADS} threads at once");
                    }
                    let id = self.next_id;
                    self.next_id = self.next_id.wrapping_add(1).max(1);
                    self.threads.push(Thread {
                        id,
                        name: f.name.clone(),
                        pc: f.entry,
                        stack: Vec::new(),
                        frames: vec![Frame {
                            ret_pc: usize::MAX,
                            locals: Some(HashMap::new()),
                        }],
                        wait: Wait::None,
                        line: f.line,
                        critical: false,
                        alive: true,
                    });
                    th.stack.push(Value::Thread(id));
                }
                Op::Kill | Op::Join => {
                    let h = pop!();
                    let Value::Thread(id) = h else {
                        fail!(
                            "type error: `{}` needs a thread handle, got {}",
                            if matches!(op, Op::Kill) {
                                "kill"
                            } else {
                                "join"
                            },
                            h.type_name()
                        );
                    };
                    if matches!(op, Op::Kill) {
                        if id == th.id {
                            return Ok(Exit::Finished);
                        }
                        for t in self.threads.iter_mut().filter(|t| t.id == id) {
                            t.alive = false;
                        }
                    } else {
                        if id == th.id {
                            fail!("a thread cannot join itself");
                        }
                        if self.threads.iter().any(|t| t.alive && t.id == id) {
                            if th.critical {
                                fail!("join blocks inside enter_critical … exit_critical");
                            }
                            th.wait = Wait::Join(id);
                            return Ok(Exit::Blocked);
                        }
                    }
                }
                Op::EnterCritical => th.critical = true,
                Op::ExitCritical => th.critical = false,
                Op::Halt => return Ok(Exit::Halt),
                Op::End => return Ok(Exit::Finished),
            }
        }
    }
}

fn placeholder() -> Thread {
    Thread {
        id: u32::MAX,
        name: String::new(),
        pc: 0,
        stack: Vec::new(),
        frames: Vec::new(),
        wait: Wait::None,
        line: 0,
        critical: false,
        alive: false,
    }
}
