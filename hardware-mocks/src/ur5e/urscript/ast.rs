//! The syntax tree the parser builds and the compiler reads.

/// Binary operators, by URScript spelling.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BinOp {
    Add,
    Sub,
    Mul,
    Div,
    Mod,
    Eq,
    Ne,
    Lt,
    Le,
    Gt,
    Ge,
}

impl BinOp {
    pub fn symbol(self) -> &'static str {
        match self {
            BinOp::Add => "+",
            BinOp::Sub => "-",
            BinOp::Mul => "*",
            BinOp::Div => "/",
            BinOp::Mod => "%",
            BinOp::Eq => "==",
            BinOp::Ne => "!=",
            BinOp::Lt => "<",
            BinOp::Le => "<=",
            BinOp::Gt => ">",
            BinOp::Ge => ">=",
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum UnOp {
    Neg,
    Not,
}

#[derive(Debug, Clone, PartialEq)]
pub enum Expr {
    Int(i32),
    Float(f64),
    Bool(bool),
    Str(String),
    Var(String),
    List(Vec<Expr>),
    /// `p[x, y, z, rx, ry, rz]`.
    Pose(Vec<Expr>),
    Index(Box<Expr>, Box<Expr>),
    Unary(UnOp, Box<Expr>),
    Binary(BinOp, Box<Expr>, Box<Expr>),
    And(Box<Expr>, Box<Expr>),
    Or(Box<Expr>, Box<Expr>),
    Call {
        name: String,
        args: Vec<Expr>,
        kwargs: Vec<(String, Expr)>,
    },
    /// `run name()`: starts a thread, evaluates to its handle.
    Run(String),
}

/// How an assignment binds its variable (URScript manual, "Scoping rules").
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Scope {
    /// No qualifier: a global of that name if one exists, else a local.
    Free,
    Global,
    Local,
}

#[derive(Debug, Clone, PartialEq)]
pub struct Stmt {
    /// 1-based source line.
    pub line: u32,
    pub kind: StmtKind,
}

#[derive(Debug, Clone, PartialEq)]
pub enum StmtKind {
    Expr(Expr),
    Assign {
        scope: Scope,
        name: String,
        index: Option<Expr>,
        value: Expr,
    },
    If {
        arms: Vec<(Expr, Vec<Stmt>)>,
        otherwise: Vec<Stmt>,
    },
    While {
        cond: Expr,
        body: Vec<Stmt>,
    },
    Def {
        name: String,
        params: Vec<String>,
        body: Vec<Stmt>,
    },
    Thread {
        name: String,
        body: Vec<Stmt>,
    },
    Return(Option<Expr>),
    Halt,
    Kill(Expr),
    Join(Expr),
    EnterCritical,
    ExitCritical,
    Break,
    Continue,
}
