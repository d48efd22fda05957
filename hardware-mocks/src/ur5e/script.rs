//! The secondary interface (TCP 30002 on a real controller): URScript text in, a program out.
//!
//! A real controller compiles and runs whatever script arrives. The mock runs only the rig's
//! own control program, read by [`super::program`], whose semantics it emulates in
//! [`super::controller`]; any other script is refused with a warning in the log.
//!
//! Real controllers also stream binary robot-state packages (robot mode data, joint data,
//! version message, …) to every client of 30002; the mock sends nothing back on this port.

use std::sync::Arc;

use tokio::io::AsyncReadExt;
use tokio::net::{TcpListener, TcpStream};

pub use super::program::{Script, ScriptError, Watchdog, WatchdogAction, is_complete, parse};
use super::shared::{Shared, accept_loop, spawn_until_shutdown};

/// Accept scripts on the secondary-interface listener until the task is dropped.
pub(super) async fn serve(listener: TcpListener, shared: Arc<Shared>) {
    accept_loop(listener, shared, "script port", |sock, peer, shared| {
        let owned = shared.clone();
        spawn_until_shutdown(shared, "script", peer, async move {
            handle(sock, &owned).await;
        });
    })
    .await;
}

async fn handle(mut sock: TcpStream, shared: &Shared) {
    let mut text = String::new();
    let mut buf = vec![0u8; 8192];
    loop {
        let n = match sock.read(&mut buf).await {
            Ok(0) | Err(_) => 0,
            Ok(n) => n,
        };
        if n > 0 {
            text.push_str(&String::from_utf8_lossy(&buf[..n]));
        }
        let complete = is_complete(&text);
        if n == 0 || complete {
            if !text.trim().is_empty() {
                run(&text, shared);
            }
            if n == 0 {
                return;
            }
            // Further scripts may follow on the same connection.
            text.clear();
        }
    }
}

fn run(text: &str, shared: &Shared) {
    match parse(text) {
        Ok(script) => {
            let now = shared.clock.now_ns();
            shared.lock().upload(script, now);
        }
        Err(e) => tracing::warn!("script refused: {e}"),
    }
}
