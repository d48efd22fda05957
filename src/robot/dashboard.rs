//! Dashboard server client (TCP 29999): power, brakes, protective-stop unlock, play/stop.
//!
//! The dashboard server (UR "Dashboard Server e-Series" manual) speaks a line protocol: on
//! connect it sends one greeting line ("Connected: Universal Robots Dashboard Server"), then
//! answers each newline-terminated command with one line. Replies are human text; a refusal
//! starts with words like "Failed", "Cannot", "could not" or "Error", so that is what the
//! client checks, and it returns the controller's own words in the error so the operator sees
//! them. A broken socket is re-opened once per command (the dashboard server closes idle or
//! overflowing connections).

use std::net::SocketAddr;
use std::time::Duration;

use rig_core::clock::Clock;
use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};
use tokio::net::TcpStream;
use tokio::net::tcp::{OwnedReadHalf, OwnedWriteHalf};

/// What went wrong talking to the dashboard server.
#[derive(Debug, Clone, thiserror::Error)]
pub enum DashboardError {
    #[error(
        "cannot reach the UR dashboard server at {addr}: {reason}; check that the robot is on and in Remote Control mode (e-Series)"
    )]
    Connect { addr: SocketAddr, reason: String },
    #[error("dashboard server at {addr} did not answer `{command}` within {timeout:?}")]
    Timeout {
        addr: SocketAddr,
        command: String,
        timeout: Duration,
    },
    #[error("dashboard `{command}` refused: \"{reply}\"{hint}")]
    Refused {
        command: String,
        reply: String,
        hint: String,
    },
    #[error("dashboard I/O error on `{command}`: {reason}")]
    Io { command: String, reason: String },
}

/// A connection to the dashboard server.
pub struct Dashboard {
    addr: SocketAddr,
    clock: Clock,
    timeout: Duration,
    io: Option<(BufReader<OwnedReadHalf>, OwnedWriteHalf)>,
    greeting: String,
}

/// Whether a dashboard reply reports a failure.
pub fn is_refusal(reply: &str) -> bool {
    let r = reply.trim_start().to_ascii_lowercase();
    [
        "failed",
        "cannot",
        "could not",
        "error",
        "not ",
        "no program",
    ]
    .iter()
    .any(|p| r.starts_with(p))
}

impl Dashboard {
    /// Connect and read the greeting. `timeout` (clock time) bounds each command.
    pub async fn connect(
        addr: SocketAddr,
        clock: Clock,
        timeout: Duration,
    ) -> Result<Self, DashboardError> {
        let mut d = Self {
            addr,
            clock,
            timeout,
            io: None,
            greeting: String::new(),
        };
        d.open().await?;
        Ok(d)
    }

    async fn open(&mut self) -> Result<(), DashboardError> {
        let addr = self.addr;
        let stream = self
            .clock
            .timeout(self.timeout, TcpStream::connect(addr))
            .await
            .map_err(|_| DashboardError::Connect {
                addr,
                reason: format!("no answer within {:?}", self.timeout),
            })?
            .map_err(|e| DashboardError::Connect {
                addr,
                reason: e.to_string(),
            })?;
        let _ = stream.set_nodelay(true);
        let (r, w) = stream.into_split();
        let mut reader = BufReader::new(r);
        let greeting = read_line(&mut reader, &self.clock, self.timeout)
            .await
            .map_err(|reason| DashboardError::Connect {
                addr,
                reason: format!("no greeting: {reason}"),
            })?;
        tracing::debug!("dashboard {addr}: {greeting}");
        self.greeting = greeting;
        self.io = Some((reader, w));
        Ok(())
    }

    /// The greeting line the server sent on connect.
    pub fn greeting(&self) -> &str {
        &self.greeting
    }

    /// Send one command and return the reply line (without checking it).
    pub async fn command(&mut self, command: &str) -> Result<String, DashboardError> {
        match self.try_command(command).await {
            Ok(r) => Ok(r),
            Err(DashboardError::Io { .. }) => {
                // The server may have closed the socket; re-open once.
                self.io = None;
                self.open().await?;
                self.try_command(command).await
            }
            Err(e) => Err(e),
        }
    }

    async fn try_command(&mut self, command: &str) -> Result<String, DashboardError> {
        if self.io.is_none() {
            self.open().await?;
        }
        let Some((reader, writer)) = self.io.as_mut() else {
            return Err(DashboardError::Io {
                command: command.into(),
                reason: "not connected".into(),
            });
        };
        let io_err = |reason: String| DashboardError::Io {
            command: command.into(),
            reason,
        };
        writer
            .write_all(format!("{command}\n").as_bytes())
            .await
            .map_err(|e| io_err(e.to_string()))?;
        match self
            .clock
            .timeout(self.timeout, read_line_raw(reader))
            .await
        {
            Err(_) => {
                self.io = None;
                Err(DashboardError::Timeout {
                    addr: self.addr,
                    command: command.into(),
                    timeout: self.timeout,
                })
            }
            Ok(Err(e)) => {
                self.io = None;
                Err(io_err(e))
            }
            Ok(Ok(line)) => {
                tracing::debug!("dashboard `{command}` -> {line}");
                Ok(line)
            }
        }
    }

    /// Send a command whose reply must not be a refusal; `hint` is appended to the refusal.
    async fn checked(&mut self, command: &str, hint: &str) -> Result<(), DashboardError> {
        let reply = self.command(command).await?;
        if is_refusal(&reply) {
            return Err(DashboardError::Refused {
                command: command.into(),
                reply,
                hint: hint.into(),
            });
        }
        Ok(())
    }

    pub async fn power_on(&mut self) -> Result<(), DashboardError> {
        self.checked(
            "power on",
            "; check the teach pendant: the robot must be in Remote Control and not in an emergency stop",
        )
        .await
    }

    pub async fn power_off(&mut self) -> Result<(), DashboardError> {
        self.checked("power off", "").await
    }

    pub async fn brake_release(&mut self) -> Result<(), DashboardError> {
        self.checked("brake release", "; power the robot on first")
            .await
    }

    /// Unlock a protective stop. UR refuses this for 5 s after the stop.
    pub async fn unlock_protective_stop(&mut self) -> Result<(), DashboardError> {
        self.checked(
            "unlock protective stop",
            "; inspect the cause of the stop, wait at least 5 s after it, then retry",
        )
        .await
    }

    /// Close the safety popup on the teach pendant (clears the operator-facing error).
    pub async fn close_safety_popup(&mut self) -> Result<(), DashboardError> {
        self.checked("close safety popup", "").await
    }

    /// Close an informational popup.
    pub async fn close_popup(&mut self) -> Result<(), DashboardError> {
        self.checked("close popup", "").await
    }

    /// Clear operator-visible errors: both popups; failures are ignored (nothing to close).
    pub async fn clear_operator_errors(&mut self) {
        let _ = self.close_safety_popup().await;
        let _ = self.close_popup().await;
    }

    pub async fn play(&mut self) -> Result<(), DashboardError> {
        self.checked("play", "; load a program first").await
    }

    pub async fn stop(&mut self) -> Result<(), DashboardError> {
        self.checked("stop", "").await
    }

    /// The robot mode word from "Robotmode: RUNNING".
    pub async fn robot_mode(&mut self) -> Result<String, DashboardError> {
        Ok(after_colon(&self.command("robotmode").await?))
    }

    /// The safety status word from "Safetystatus: NORMAL".
    pub async fn safety_status(&mut self) -> Result<String, DashboardError> {
        Ok(after_colon(&self.command("safetystatus").await?))
    }

    /// The program state line (`PLAYING transforce_rig`, `STOPPED <unnamed>`).
    pub async fn program_state(&mut self) -> Result<String, DashboardError> {
        self.command("programState").await
    }
}

fn after_colon(s: &str) -> String {
    s.split_once(':')
        .map(|(_, r)| r.trim().to_owned())
        .unwrap_or_else(|| s.trim().to_owned())
}

async fn read_line_raw(r: &mut BufReader<OwnedReadHalf>) -> Result<String, String> {
    let mut line = String::new();
    let n = r.read_line(&mut line).await.map_err(|e| e.to_string())?;
    if n == 0 {
        return Err("connection closed".into());
    }
    Ok(line.trim_end_matches(['\r', '\n']).to_owned())
}

async fn read_line(
    r: &mut BufReader<OwnedReadHalf>,
    clock: &Clock,
    timeout: Duration,
) -> Result<String, String> {
    clock
        .timeout(timeout, read_line_raw(r))
        .await
        .map_err(|_| format!("nothing within {timeout:?}"))?
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::net::TcpListener;

    #[test]
    fn refusals_are_recognised() {
        assert!(is_refusal(
            "Cannot unlock protective stop until 5s after occurrence. Always inspect cause of protective stop before unlocking"
        ));
        assert!(is_refusal("Failed to execute: play"));
        assert!(!is_refusal("Protective stop releasing"));
        assert!(!is_refusal("Powering on"));
        assert!(!is_refusal("Brake releasing"));
    }

    #[tokio::test]
    async fn line_protocol_round_trip_and_refusal_error() {
        let l = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = l.local_addr().unwrap();
        tokio::spawn(async move {
            let (s, _) = l.accept().await.unwrap();
            let (r, mut w) = s.into_split();
            w.write_all(b"Connected: Universal Robots Dashboard Server\n")
                .await
                .unwrap();
            let mut r = BufReader::new(r);
            let mut line = String::new();
            while r.read_line(&mut line).await.unwrap() > 0 {
                let reply = match line.trim() {
                    "robotmode" => "Robotmode: RUNNING",
                    "unlock protective stop" => {
                        "Cannot unlock protective stop until 5s after occurrence."
                    }
                    _ => "ok",
                };
                w.write_all(format!("{reply}\n").as_bytes()).await.unwrap();
                line.clear();
            }
        });
        let mut d = Dashboard::connect(addr, Clock::system(), Duration::from_secs(1))
            .await
            .unwrap();
        assert!(d.greeting().contains("Dashboard"));
        assert_eq!(d.robot_mode().await.unwrap(), "RUNNING");
        let e = d.unlock_protective_stop().await.unwrap_err();
        assert!(e.to_string().contains("5 s"), "{e}");
    }
}
