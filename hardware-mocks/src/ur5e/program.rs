//! The rig's control program as the simulated controller reads it: whether an upload is the
//! rig's own program (recognised by [`control::PROGRAM_MARKER`]), its `def` name and every
//! `rtde_set_watchdog(variable, min_frequency, action)` call (URScript manual; `action`
//! defaults to "pause"). The controller model ([`super::controller`]) emulates what the program
//! does; the secondary interface ([`super::script`]) receives its text.

use rig_core::control;

/// What the watchdog does when its variable is not updated in time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WatchdogAction {
    Ignore,
    Pause,
    Stop,
}

/// One `rtde_set_watchdog` call.
#[derive(Debug, Clone, PartialEq)]
pub struct Watchdog {
    pub variable: String,
    pub min_hz: f64,
    pub action: WatchdogAction,
}

/// A script the mock can run.
#[derive(Debug, Clone, PartialEq)]
pub struct Script {
    pub name: String,
    pub watchdogs: Vec<Watchdog>,
}

/// Why a script is not run.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ScriptError {
    #[error(
        "script is not the rig's control program (no {:?} line): the mock only runs the rig's program",
        control::PROGRAM_MARKER
    )]
    NotRigProgram,
    #[error("bad rtde_set_watchdog call: {0}")]
    BadWatchdog(String),
}

/// Whether `text` holds a complete top-level `def … end` block.
pub fn is_complete(text: &str) -> bool {
    let mut seen_def = false;
    for line in text.lines() {
        if line.starts_with("def ") {
            seen_def = true;
        } else if seen_def && line.trim_end() == "end" {
            return true;
        }
    }
    false
}

fn unquote(s: &str) -> Option<&str> {
    let s = s.trim();
    s.strip_prefix('"')
        .and_then(|r| r.strip_suffix('"'))
        .or_else(|| s.strip_prefix('\'').and_then(|r| r.strip_suffix('\'')))
}

fn parse_watchdog(args: &str) -> Result<Watchdog, ScriptError> {
    let bad = || ScriptError::BadWatchdog(args.to_owned());
    let parts: Vec<&str> = args.split(',').map(str::trim).collect();
    if !(2..=3).contains(&parts.len()) {
        return Err(bad());
    }
    let variable = unquote(parts[0]).ok_or_else(bad)?.to_owned();
    let min_hz: f64 = parts[1].parse().map_err(|_| bad())?;
    let action = match parts.get(2) {
        None => WatchdogAction::Pause,
        Some(a) => {
            let a = a
                .strip_prefix("action")
                .map(|r| r.trim_start().trim_start_matches('='))
                .unwrap_or(a);
            match unquote(a).ok_or_else(bad)? {
                "ignore" => WatchdogAction::Ignore,
                "pause" => WatchdogAction::Pause,
                "stop" => WatchdogAction::Stop,
                _ => return Err(bad()),
            }
        }
    };
    Ok(Watchdog {
        variable,
        min_hz,
        action,
    })
}

/// Parse an uploaded script.
pub fn parse(text: &str) -> Result<Script, ScriptError> {
    if !text.lines().any(|l| l.trim() == control::PROGRAM_MARKER) {
        return Err(ScriptError::NotRigProgram);
    }
    let name = text
        .lines()
        .find_map(|l| l.strip_prefix("def "))
        .and_then(|r| r.split('(').next())
        .map(|n| n.trim().to_owned())
        .filter(|n| !n.is_empty())
        .unwrap_or_else(|| control::PROGRAM_NAME.to_owned());
    let mut watchdogs = Vec::new();
    for line in text.lines() {
        let l = line.trim();
        if l.starts_with('#') {
            continue;
        }
        if let Some(rest) = l.strip_prefix("rtde_set_watchdog(") {
            let args = rest.rsplit_once(')').map(|(a, _)| a).unwrap_or(rest);
            watchdogs.push(parse_watchdog(args)?);
        }
    }
    Ok(Script { name, watchdogs })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_the_rigs_program_header_and_watchdog() {
        let text = format!(
            "def {}():\n  {}\n  rtde_set_watchdog(\"input_int_register_26\", 10.0, \"stop\")\n  while True:\n    sync()\n  end\nend\n",
            control::PROGRAM_NAME,
            control::PROGRAM_MARKER
        );
        assert!(is_complete(&text));
        assert!(!is_complete(&text[..text.len() - 4]));
        let s = parse(&text).unwrap();
        assert_eq!(s.name, control::PROGRAM_NAME);
        assert_eq!(
            s.watchdogs,
            vec![Watchdog {
                variable: "input_int_register_26".into(),
                min_hz: 10.0,
                action: WatchdogAction::Stop
            }]
        );
        assert_eq!(
            parse("def f():\n  movel(p)\nend\n"),
            Err(ScriptError::NotRigProgram)
        );
        assert_eq!(
            parse_watchdog("\"x\", 5").unwrap().action,
            WatchdogAction::Pause
        );
    }
}
