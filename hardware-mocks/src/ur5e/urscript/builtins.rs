//! The built-in functions the interpreter knows, with the parameter names and defaults of the
//! URScript manual (e-Series Script Manual: "Module motion", "Module interfaces", "Module
//! math", "Module internals"). A call to anything else is refused when the script is compiled.
//!
//! Motion and register functions act on the controller through [`Robot`]. Refused at run time
//! (a runtime error, which stops the program): a register address outside 0..=47 (int and
//! float registers; 0..=127 for booleans), a value of the wrong type, a `movel` to a
//! non-finite pose or with a non-finite or non-positive `a` or `v`, a `movel` with a time `t`
//! or blend radius `r` other than 0 (not modelled), `stopl` with a non-finite or non-positive
//! deceleration, `set_tcp` with a non-finite pose, `rtde_set_watchdog` on a name that is not an
//! RTDE input variable or with an action other than "ignore", "pause" or "stop".

use rig_core::pose::{self, Pose};
use rig_core::rtde::fields;

use super::value::Value;
use super::{Robot, Watchdog, WatchdogAction};

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Builtin {
    ReadInputInt,
    ReadInputFloat,
    ReadInputBool,
    WriteOutputInt,
    WriteOutputFloat,
    WriteOutputBool,
    GetActualTcpPose,
    GetTargetTcpPose,
    Movel,
    Stopl,
    SetTcp,
    GetTcpOffset,
    PoseTrans,
    PoseInv,
    PoseAdd,
    PoseSub,
    PoseDist,
    Norm,
    Sqrt,
    Fabs,
    Floor,
    Sync,
    Sleep,
    RtdeSetWatchdog,
    Textmsg,
    ToStr,
}

/// A parameter's default.
#[derive(Debug, Clone, Copy)]
enum Dflt {
    Required,
    Float(f64),
    Int(i32),
    Str(&'static str),
}

use Builtin as B;
use Dflt::*;

/// A built-in's parameters: name and default, in order.
type Params = &'static [(&'static str, Dflt)];

/// Name, function and parameters of every built-in.
const TABLE: &[(&str, Builtin, Params)] = &[
    (
        "read_input_integer_register",
        B::ReadInputInt,
        &[("address", Required)],
    ),
    (
        "read_input_float_register",
        B::ReadInputFloat,
        &[("address", Required)],
    ),
    (
        "read_input_boolean_register",
        B::ReadInputBool,
        &[("address", Required)],
    ),
    (
        "write_output_integer_register",
        B::WriteOutputInt,
        &[("address", Required), ("value", Required)],
    ),
    (
        "write_output_float_register",
        B::WriteOutputFloat,
        &[("address", Required), ("value", Required)],
    ),
    (
        "write_output_boolean_register",
        B::WriteOutputBool,
        &[("address", Required), ("value", Required)],
    ),
    ("get_actual_tcp_pose", B::GetActualTcpPose, &[]),
    ("get_target_tcp_pose", B::GetTargetTcpPose, &[]),
    (
        "movel",
        B::Movel,
        &[
            ("pose", Required),
            ("a", Float(1.2)),
            ("v", Float(0.25)),
            ("t", Int(0)),
            ("r", Int(0)),
        ],
    ),
    ("stopl", B::Stopl, &[("a", Required)]),
    ("set_tcp", B::SetTcp, &[("pose", Required)]),
    ("get_tcp_offset", B::GetTcpOffset, &[]),
    (
        "pose_trans",
        B::PoseTrans,
        &[("p_from", Required), ("p_from_to", Required)],
    ),
    ("pose_inv", B::PoseInv, &[("p_from", Required)]),
    (
        "pose_add",
        B::PoseAdd,
        &[("p_1", Required), ("p_2", Required)],
    ),
    (
        "pose_sub",
        B::PoseSub,
        &[("p_to", Required), ("p_from", Required)],
    ),
    (
        "pose_dist",
        B::PoseDist,
        &[("p_from", Required), ("p_to", Required)],
    ),
    ("norm", B::Norm, &[("a", Required)]),
    ("sqrt", B::Sqrt, &[("f", Required)]),
    ("fabs", B::Fabs, &[("f", Required)]),
    ("floor", B::Floor, &[("f", Required)]),
    ("sync", B::Sync, &[]),
    ("sleep", B::Sleep, &[("t", Required)]),
    (
        "rtde_set_watchdog",
        B::RtdeSetWatchdog,
        &[
            ("variable_name", Required),
            ("min_frequency", Required),
            ("action", Str("pause")),
        ],
    ),
    ("textmsg", B::Textmsg, &[("s1", Required), ("s2", Str(""))]),
    ("to_str", B::ToStr, &[("val", Required)]),
];

fn entry(f: Builtin) -> &'static (&'static str, Builtin, Params) {
    TABLE
        .iter()
        .find(|e| e.1 == f)
        .expect("every built-in is in the table")
}

/// The built-in called `name`.
pub fn lookup(name: &str) -> Option<Builtin> {
    TABLE.iter().find(|e| e.0 == name).map(|e| e.1)
}

/// The built-in's URScript name.
pub fn name(f: Builtin) -> &'static str {
    entry(f).0
}

/// Checks a call's argument list against the parameters: not too many positional arguments,
/// keywords that exist and are not also given by position, every required parameter given.
pub fn check_call<'k>(
    f: Builtin,
    positional: usize,
    keywords: impl Iterator<Item = &'k str>,
) -> Result<(), String> {
    let (fname, _, params) = entry(f);
    if positional > params.len() {
        return Err(format!(
            "`{fname}` takes at most {} argument(s), {positional} given",
            params.len()
        ));
    }
    let mut given = vec![false; params.len()];
    given[..positional].fill(true);
    for k in keywords {
        let Some(i) = params.iter().position(|(n, _)| *n == k) else {
            return Err(format!("`{fname}` has no parameter `{k}`"));
        };
        if given[i] {
            return Err(format!("`{fname}`: parameter `{k}` given twice"));
        }
        given[i] = true;
    }
    for ((n, d), g) in params.iter().zip(&given) {
        if !g && matches!(d, Required) {
            return Err(format!("`{fname}`: missing argument `{n}`"));
        }
    }
    Ok(())
}

/// The full argument list, in parameter order, defaults filled in. `values` holds the
/// positional arguments, then one value per keyword in `keywords`.
fn bind(f: Builtin, mut values: Vec<Value>, keywords: &[String]) -> Result<Vec<Value>, String> {
    check_call(
        f,
        values.len() - keywords.len(),
        keywords.iter().map(String::as_str),
    )?;
    let (_, _, params) = entry(f);
    let kw_values = values.split_off(values.len() - keywords.len());
    let mut out: Vec<Option<Value>> = values.into_iter().map(Some).collect();
    out.resize(params.len(), None);
    for (k, v) in keywords.iter().zip(kw_values) {
        if let Some(i) = params.iter().position(|(n, _)| n == k) {
            out[i] = Some(v);
        }
    }
    Ok(out
        .into_iter()
        .zip(params.iter())
        .map(|(v, (_, d))| {
            v.unwrap_or(match d {
                Float(x) => Value::Float(*x),
                Int(x) => Value::Int(*x),
                Str(s) => Value::Str((*s).to_owned()),
                Required => Value::None,
            })
        })
        .collect())
}

/// What a blocked thread waits for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Wait {
    /// Not blocked.
    None,
    /// The next cycle (`sync()`).
    NextCycle,
    /// The motion with this id to end (`movel`).
    Motion(u64),
    /// The arm at rest (`stopl`).
    Rest,
    /// Controller time, ns (`sleep`).
    Until(u64),
    /// Thread with this id to end (`join`).
    Join(u32),
}

/// What a built-in call gives: a value now, or a wait after which it evaluates to `None`.
pub enum Flow {
    Value(Value),
    Block(Wait),
}

fn num(v: &Value, what: &str) -> Result<f64, String> {
    v.as_f64()
        .ok_or_else(|| format!("type error: {what} must be a number, got {}", v.type_name()))
}

fn pose_arg(v: &Value, what: &str) -> Result<Pose, String> {
    match v {
        Value::Pose(p) => Ok(*p),
        other => Err(format!(
            "type error: {what} must be a pose, got {}",
            other.type_name()
        )),
    }
}

fn address(v: &Value, max: i32) -> Result<usize, String> {
    match *v {
        Value::Int(n) if (0..=max).contains(&n) => Ok(n as usize),
        Value::Int(n) => Err(format!("register address {n} out of range 0..{max}")),
        ref other => Err(format!(
            "type error: a register address must be an int, got {}",
            other.type_name()
        )),
    }
}

fn finite_pose(p: &Pose) -> bool {
    p.to_array().iter().all(|x| x.is_finite())
}

/// `p_to` relative to `p_from` as the manual's `pose_sub` defines it: positions subtracted,
/// rotations `R_to · R_fromᵀ`.
fn pose_sub(p_to: &Pose, p_from: &Pose) -> Pose {
    let r = p_to.rotation() * p_from.rotation().transpose();
    Pose::from_parts(
        &(p_to.position() - p_from.position()),
        &pose::rotation_to_rotvec(&r),
    )
}

/// Executes built-in `f` with the evaluated arguments (`values`: positional, then keyword
/// values in the order of `keywords`).
pub fn call(
    f: Builtin,
    values: Vec<Value>,
    keywords: &[String],
    robot: &mut dyn Robot,
) -> Result<Flow, String> {
    let a = bind(f, values, keywords)?;
    let v = |x: Value| Ok(Flow::Value(x));
    match f {
        B::ReadInputInt => v(Value::Int(robot.input_int(address(&a[0], 47)?))),
        B::ReadInputFloat => v(Value::Float(robot.input_float(address(&a[0], 47)?))),
        B::ReadInputBool => v(Value::Bool(robot.input_bool(address(&a[0], 127)?))),
        B::WriteOutputInt => {
            let n = address(&a[0], 47)?;
            let Value::Int(x) = a[1] else {
                return Err(format!(
                    "type error: an integer register takes an int, got {}",
                    a[1].type_name()
                ));
            };
            robot.set_output_int(n, x);
            v(Value::None)
        }
        B::WriteOutputFloat => {
            let n = address(&a[0], 47)?;
            robot.set_output_float(n, num(&a[1], "a float register value")?);
            v(Value::None)
        }
        B::WriteOutputBool => {
            let n = address(&a[0], 127)?;
            let Value::Bool(x) = a[1] else {
                return Err(format!(
                    "type error: a boolean register takes a bool, got {}",
                    a[1].type_name()
                ));
            };
            robot.set_output_bool(n, x);
            v(Value::None)
        }
        B::GetActualTcpPose => v(Value::Pose(robot.actual_tcp_pose())),
        B::GetTargetTcpPose => v(Value::Pose(robot.target_tcp_pose())),
        B::Movel => {
            let target = match &a[0] {
                Value::Pose(p) => *p,
                Value::List(_) => {
                    return Err(
                        "movel to joint positions is not supported (no kinematics model)".into(),
                    );
                }
                other => {
                    return Err(format!(
                        "type error: movel needs a pose, got {}",
                        other.type_name()
                    ));
                }
            };
            let (acc, vel) = (num(&a[1], "a")?, num(&a[2], "v")?);
            let (t, r) = (num(&a[3], "t")?, num(&a[4], "r")?);
            if !finite_pose(&target) {
                return Err(format!("movel to a non-finite pose {}", a[0].to_text()));
            }
            if !(acc.is_finite() && acc > 0.0 && vel.is_finite() && vel > 0.0) {
                return Err(format!(
                    "movel needs a finite, positive a and v (a={acc}, v={vel})"
                ));
            }
            if t != 0.0 || r != 0.0 {
                return Err(format!(
                    "movel with t={t} or r={r} is not supported (only t=0, r=0)"
                ));
            }
            Ok(Flow::Block(Wait::Motion(robot.movel(target, acc, vel))))
        }
        B::Stopl => {
            let dec = num(&a[0], "a")?;
            if !(dec.is_finite() && dec > 0.0) {
                return Err(format!("stopl needs a finite, positive a (a={dec})"));
            }
            robot.stopl(dec);
            Ok(Flow::Block(Wait::Rest))
        }
        B::SetTcp => {
            let p = pose_arg(&a[0], "the TCP offset")?;
            if !finite_pose(&p) {
                return Err(format!("set_tcp with a non-finite pose {}", a[0].to_text()));
            }
            robot.set_tcp(p);
            v(Value::None)
        }
        B::GetTcpOffset => v(Value::Pose(robot.tcp_offset())),
        B::PoseTrans => v(Value::Pose(pose::pose_trans(
            &pose_arg(&a[0], "p_from")?,
            &pose_arg(&a[1], "p_from_to")?,
        ))),
        B::PoseInv => v(Value::Pose(pose::pose_inv(&pose_arg(&a[0], "p_from")?))),
        B::PoseAdd => v(Value::Pose(pose::pose_add(
            &pose_arg(&a[0], "p_1")?,
            &pose_arg(&a[1], "p_2")?,
        ))),
        B::PoseSub => v(Value::Pose(pose_sub(
            &pose_arg(&a[0], "p_to")?,
            &pose_arg(&a[1], "p_from")?,
        ))),
        B::PoseDist => v(Value::Float(pose::translation_distance(
            &pose_arg(&a[0], "p_from")?,
            &pose_arg(&a[1], "p_to")?,
        ))),
        B::Norm => match &a[0] {
            Value::List(items) => {
                let mut sum = 0.0;
                for x in items {
                    let x = num(x, "a list element")?;
                    sum += x * x;
                }
                v(Value::Float(sum.sqrt()))
            }
            x => v(Value::Float(num(x, "the argument of norm")?.abs())),
        },
        B::Sqrt => {
            let x = num(&a[0], "f")?;
            if x < 0.0 {
                return Err(format!("sqrt of a negative number ({x})"));
            }
            v(Value::Float(x.sqrt()))
        }
        B::Fabs => v(Value::Float(num(&a[0], "f")?.abs())),
        B::Floor => {
            let x = num(&a[0], "f")?.floor();
            if !(x >= i32::MIN as f64 && x <= i32::MAX as f64) {
                return Err(format!("floor({x}) does not fit in an int"));
            }
            v(Value::Int(x as i32))
        }
        B::Sync => Ok(Flow::Block(Wait::NextCycle)),
        B::Sleep => {
            let t = num(&a[0], "t")?;
            if !(t.is_finite() && t >= 0.0) {
                return Err(format!("sleep needs a finite, non-negative time (t={t})"));
            }
            let until = robot.now_ns().saturating_add((t * 1e9).round() as u64);
            Ok(Flow::Block(Wait::Until(until)))
        }
        B::RtdeSetWatchdog => {
            let Value::Str(variable) = &a[0] else {
                return Err("type error: variable_name must be a string".into());
            };
            if fields::input_type(variable).is_none() {
                return Err(format!("{variable:?} is not an RTDE input variable"));
            }
            let min_hz = num(&a[1], "min_frequency")?;
            if !(min_hz.is_finite() && min_hz >= 0.0) {
                return Err(format!(
                    "min_frequency must be finite and ≥ 0, got {min_hz}"
                ));
            }
            let action = match &a[2] {
                Value::Str(s) if s == "ignore" => WatchdogAction::Ignore,
                Value::Str(s) if s == "pause" => WatchdogAction::Pause,
                Value::Str(s) if s == "stop" => WatchdogAction::Stop,
                other => {
                    return Err(format!(
                        "watchdog action must be \"ignore\", \"pause\" or \"stop\", got {}",
                        other.to_text()
                    ));
                }
            };
            robot.set_watchdog(Watchdog {
                variable: variable.clone(),
                min_hz,
                action,
            });
            v(Value::None)
        }
        B::Textmsg => {
            tracing::info!(target: "urscript", "textmsg: {}{}", a[0].to_text(), a[1].to_text());
            v(Value::None)
        }
        B::ToStr => v(Value::Str(a[0].to_text())),
    }
}
