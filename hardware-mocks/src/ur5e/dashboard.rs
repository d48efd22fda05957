//! The dashboard server (TCP 29999 on a real controller): newline-terminated text commands,
//! one reply line each, in the wording of UR's dashboard server where known.
//!
//! Differences from a real controller, on purpose: `power on` goes straight to IDLE (no
//! seconds-long POWER_ON/booting phase), `play` restarts the last uploaded script (there are no
//! .urp files), and `load`/`popup`/installation commands are not understood.

use std::sync::Arc;

use rig_core::control::{robot_mode_name, runtime_state, runtime_state_name, safety_mode_name};
use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};
use tokio::net::{TcpListener, TcpStream};

use super::shared::{Shared, accept_loop, spawn_until_shutdown};

/// First line sent to every dashboard client.
pub const GREETING: &str = "Connected: Universal Robots Dashboard Server";

pub(super) async fn serve(listener: TcpListener, shared: Arc<Shared>) {
    accept_loop(listener, shared, "dashboard", |sock, peer, shared| {
        let owned = shared.clone();
        spawn_until_shutdown(shared, "dashboard", peer, async move {
            if let Err(e) = handle(sock, &owned).await {
                tracing::debug!(%peer, "dashboard client error: {e}");
            }
        });
    })
    .await;
}

async fn handle(sock: TcpStream, shared: &Shared) -> std::io::Result<()> {
    let (rd, mut wr) = sock.into_split();
    wr.write_all(format!("{GREETING}\n").as_bytes()).await?;
    let mut lines = BufReader::new(rd).lines();
    while let Some(line) = lines.next_line().await? {
        let cmd = line.trim();
        if cmd.is_empty() {
            continue;
        }
        let (reply, quit) = execute(cmd, shared);
        tracing::debug!(command = cmd, reply = %reply, "dashboard");
        wr.write_all(format!("{reply}\n").as_bytes()).await?;
        if quit {
            break;
        }
    }
    Ok(())
}

/// Execute one command; returns the reply line and whether to close the connection.
pub(super) fn execute(cmd: &str, shared: &Shared) -> (String, bool) {
    let now = shared.clock.now_ns();
    let mut c = shared.lock();
    let program_name = c
        .program
        .as_ref()
        .map(|p| p.name.clone())
        .unwrap_or_else(|| "<unnamed>".to_owned());
    let reply = match cmd.to_ascii_lowercase().as_str() {
        "power on" => match c.power_on() {
            Ok(()) => "Powering on".to_owned(),
            Err(_) => "Failed to execute: power on".to_owned(),
        },
        "power off" => {
            c.power_off(now);
            "Powering off".to_owned()
        }
        "brake release" => match c.brake_release() {
            Ok(()) => "Brake releasing".to_owned(),
            Err(_) => "Failed to execute: brake release".to_owned(),
        },
        "unlock protective stop" => match c.unlock_protective_stop(now) {
            Ok(()) => "Protective stop releasing".to_owned(),
            Err(msg) if msg.starts_with("Cannot") => msg,
            Err(_) => "Failed to execute: unlock protective stop".to_owned(),
        },
        "close safety popup" => "closing safety popup".to_owned(),
        "close popup" => "closing popup".to_owned(),
        "play" => {
            let r = if c.runtime_state == runtime_state::PAUSED {
                c.resume_program(now)
            } else {
                c.start_program(now)
            };
            match r {
                Ok(()) => "Starting program".to_owned(),
                Err(_) => "Failed to execute: play".to_owned(),
            }
        }
        "stop" => {
            if matches!(
                c.runtime_state,
                runtime_state::PLAYING | runtime_state::PAUSED
            ) {
                c.stop_program(now);
                "Stopped".to_owned()
            } else {
                "Failed to execute: stop".to_owned()
            }
        }
        "pause" => {
            if c.runtime_state == runtime_state::PLAYING {
                c.pause_program(now);
                "Pausing program".to_owned()
            } else {
                "Failed to execute: pause".to_owned()
            }
        }
        "robotmode" => format!("Robotmode: {}", robot_mode_name(c.robot_mode)),
        "safetymode" => format!("Safetymode: {}", safety_mode_name(c.safety_mode)),
        "safetystatus" => format!("Safetystatus: {}", safety_mode_name(c.safety_mode)),
        "programstate" => format!("{} {program_name}", runtime_state_name(c.runtime_state)),
        "running" => format!(
            "Program running: {}",
            c.runtime_state == runtime_state::PLAYING
        ),
        "get loaded program" => match &c.program {
            Some(p) => format!("Loaded program: {}", p.name),
            None => "No program loaded".to_owned(),
        },
        "is in remote control" => "true".to_owned(),
        "polyscopeversion" => {
            let (a, b, d, e) = shared.cfg.controller_version;
            format!("URSoftware {a}.{b}.{d}.{e} (simulated)")
        }
        "quit" => return ("Disconnected".to_owned(), true),
        _ => format!("could not understand: '{cmd}'"),
    };
    (reply, false)
}
