//! URScript values and the arithmetic and comparison operators on them.
//!
//! Types (URScript manual, "Numbers, Variables, and Types"): `int` (32 bits), `float`, `bool`,
//! `string`, `pose` (`p[x, y, z, rx, ry, rz]`), lists, and the thread handles `run` returns.
//! A float here is an `f64` (the controller's own precision is not modelled).
//!
//! Arithmetic: int op int is an int for `+ - * %` (an overflow of 32 bits is a runtime error,
//! never a silent wrap); with a float on either side the result is a float. **`/` always gives
//! a float** (`7 / 2` is `3.5`): the manual does not spell out integer division, and a float
//! never truncates silently; the rig's program does not divide. An integer `/` or `%` by zero is
//! a runtime error; a float division by zero follows IEEE 754 (±inf or NaN).
//!
//! Comparisons between numbers (int or float, mixed freely) follow IEEE 754: every ordering
//! and `==` with a NaN is False (and `!=` True), so `v > 0 and v < 1000000` is False for NaN
//! and for ±inf — the rig's program relies on this. `==`/`!=` also compare bools, strings,
//! poses, lists and thread handles of the same type; comparing values of unrelated types is a
//! type error.

use rig_core::pose::Pose;

use super::ast::{BinOp, UnOp};

#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    Int(i32),
    Float(f64),
    Bool(bool),
    Str(String),
    Pose(Pose),
    List(Vec<Value>),
    /// A thread handle (`run t()`), by thread id.
    Thread(u32),
    /// What a call without a return value evaluates to.
    None,
}

impl Value {
    /// The type's name as URScript error messages spell it.
    pub fn type_name(&self) -> &'static str {
        match self {
            Value::Int(_) => "int",
            Value::Float(_) => "float",
            Value::Bool(_) => "bool",
            Value::Str(_) => "string",
            Value::Pose(_) => "pose",
            Value::List(_) => "list",
            Value::Thread(_) => "thread",
            Value::None => "none",
        }
    }

    /// The value of a number (int or float) as a float.
    pub fn as_f64(&self) -> Option<f64> {
        match *self {
            Value::Int(i) => Some(i as f64),
            Value::Float(f) => Some(f),
            _ => None,
        }
    }

    /// The value as URScript's `to_str` and `textmsg` print it.
    pub fn to_text(&self) -> String {
        fn float(f: f64) -> String {
            rig_core::urscript::fmt_f64(f)
        }
        match self {
            Value::Int(i) => i.to_string(),
            Value::Float(f) => float(*f),
            Value::Bool(b) => if *b { "True" } else { "False" }.to_owned(),
            Value::Str(s) => s.clone(),
            Value::Pose(p) => format!("p[{}]", p.to_array().map(float).join(", ")),
            Value::List(v) => format!(
                "[{}]",
                v.iter().map(Value::to_text).collect::<Vec<_>>().join(", ")
            ),
            Value::Thread(id) => format!("<thread {id}>"),
            Value::None => "None".to_owned(),
        }
    }
}

fn mismatch(op: &str, a: &Value, b: &Value) -> String {
    format!(
        "type error: {} {op} {} is not defined",
        a.type_name(),
        b.type_name()
    )
}

/// `op a`.
pub fn unary(op: UnOp, a: &Value) -> Result<Value, String> {
    match (op, a) {
        (UnOp::Neg, Value::Int(i)) => i
            .checked_neg()
            .map(Value::Int)
            .ok_or_else(|| "integer overflow in -".to_owned()),
        (UnOp::Neg, Value::Float(f)) => Ok(Value::Float(-f)),
        (UnOp::Not, Value::Bool(b)) => Ok(Value::Bool(!b)),
        (UnOp::Neg, v) => Err(format!("type error: -{} is not defined", v.type_name())),
        (UnOp::Not, v) => Err(format!(
            "type error: `not` needs a bool, got {}",
            v.type_name()
        )),
    }
}

/// `a op b` for the arithmetic and comparison operators.
pub fn binary(op: BinOp, a: &Value, b: &Value) -> Result<Value, String> {
    use BinOp::*;
    match op {
        Eq | Ne => equal(a, b)
            .map(|eq| Value::Bool(eq == (op == Eq)))
            .ok_or_else(|| mismatch(op.symbol(), a, b)),
        Lt | Le | Gt | Ge => {
            let (Some(x), Some(y)) = (a.as_f64(), b.as_f64()) else {
                return Err(mismatch(op.symbol(), a, b));
            };
            Ok(Value::Bool(match op {
                Lt => x < y,
                Le => x <= y,
                Gt => x > y,
                _ => x >= y,
            }))
        }
        Add | Sub | Mul | Div | Mod => arithmetic(op, a, b),
    }
}

fn arithmetic(op: BinOp, a: &Value, b: &Value) -> Result<Value, String> {
    use BinOp::*;
    if let (Value::Int(x), Value::Int(y)) = (a, b) {
        let (x, y) = (*x, *y);
        let r = match op {
            Add => x.checked_add(y),
            Sub => x.checked_sub(y),
            Mul => x.checked_mul(y),
            Div => {
                if y == 0 {
                    return Err("division by zero".into());
                }
                return Ok(Value::Float(x as f64 / y as f64));
            }
            _ => {
                if y == 0 {
                    return Err("modulo by zero".into());
                }
                x.checked_rem(y)
            }
        };
        return r
            .map(Value::Int)
            .ok_or_else(|| format!("integer overflow in {x} {} {y}", op.symbol()));
    }
    let (Some(x), Some(y)) = (a.as_f64(), b.as_f64()) else {
        return Err(mismatch(op.symbol(), a, b));
    };
    Ok(Value::Float(match op {
        Add => x + y,
        Sub => x - y,
        Mul => x * y,
        Div => x / y,
        _ => x % y,
    }))
}

/// `a == b`, `None` when the types cannot be compared.
fn equal(a: &Value, b: &Value) -> Option<bool> {
    if let (Some(x), Some(y)) = (a.as_f64(), b.as_f64()) {
        return Some(x == y);
    }
    match (a, b) {
        (Value::Bool(x), Value::Bool(y)) => Some(x == y),
        (Value::Str(x), Value::Str(y)) => Some(x == y),
        (Value::Pose(x), Value::Pose(y)) => Some(x.to_array() == y.to_array()),
        (Value::Thread(x), Value::Thread(y)) => Some(x == y),
        (Value::None, Value::None) => Some(true),
        (Value::List(x), Value::List(y)) => {
            if x.len() != y.len() {
                return Some(false);
            }
            let mut all = true;
            for (p, q) in x.iter().zip(y) {
                all &= equal(p, q)?;
            }
            Some(all)
        }
        _ => None,
    }
}

/// `a[i]` for lists and poses (a pose's elements are floats).
pub fn index(a: &Value, i: &Value) -> Result<Value, String> {
    let Value::Int(i) = *i else {
        return Err(format!(
            "type error: an index must be an int, got {}",
            i.type_name()
        ));
    };
    let out_of_range = |len: usize| format!("index {i} out of range for length {len}");
    match a {
        Value::List(v) => usize::try_from(i)
            .ok()
            .and_then(|i| v.get(i))
            .cloned()
            .ok_or_else(|| out_of_range(v.len())),
        Value::Pose(p) => usize::try_from(i)
            .ok()
            .and_then(|i| p.to_array().get(i).copied())
            .map(Value::Float)
            .ok_or_else(|| out_of_range(6)),
        v => Err(format!("type error: cannot index a {}", v.type_name())),
    }
}

/// `a[i] = v`: the updated container.
pub fn set_index(a: &Value, i: &Value, v: Value) -> Result<Value, String> {
    let Value::Int(i) = *i else {
        return Err(format!(
            "type error: an index must be an int, got {}",
            i.type_name()
        ));
    };
    match a {
        Value::List(items) => {
            let mut items = items.clone();
            let len = items.len();
            let slot = usize::try_from(i)
                .ok()
                .and_then(|i| items.get_mut(i))
                .ok_or_else(|| format!("index {i} out of range for length {len}"))?;
            *slot = v;
            Ok(Value::List(items))
        }
        Value::Pose(p) => {
            let x = v.as_f64().ok_or_else(|| {
                format!(
                    "type error: a pose element must be a number, got {}",
                    v.type_name()
                )
            })?;
            let mut arr = p.to_array();
            let slot = usize::try_from(i)
                .ok()
                .and_then(|i| arr.get_mut(i))
                .ok_or_else(|| format!("index {i} out of range for length 6"))?;
            *slot = x;
            Ok(Value::Pose(Pose::from_array(arr)))
        }
        other => Err(format!("type error: cannot index a {}", other.type_name())),
    }
}
