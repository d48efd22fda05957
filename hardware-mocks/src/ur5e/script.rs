//! The secondary interface (TCP 30002 on a real controller): URScript text in, a program out.
//!
//! A real controller compiles and runs whatever script arrives; so does the mock, with its
//! interpreter ([`super::urscript`]): the text is compiled ([`Program::parse`]) and started,
//! replacing any running program. A script that does not compile is logged as an error naming
//! its line and statement, the running program stops, and nothing is started.
//!
//! Where a script ends: when the connection closes, or as soon as the text received is a whole
//! script ending with a top-level statement ([`is_complete`]; the rig's program ends with the
//! call that runs it), or when a script of definitions only has had all its blocks closed and
//! nothing more arrived for [`QUIET`] (a client that sends `def prog(): … end` and keeps the
//! connection open). Further scripts may follow on the same connection.
//!
//! Real controllers also stream binary robot-state packages (robot mode data, joint data,
//! version message, …) to every client of 30002; the mock sends nothing back on this port.

use std::sync::Arc;
use std::time::Duration;

use tokio::io::AsyncReadExt;
use tokio::net::{TcpListener, TcpStream};

use super::shared::{Shared, accept_loop, spawn_until_shutdown};
pub use super::urscript::{Program, ScriptError, Watchdog, WatchdogAction, is_closed, is_complete};

/// How long a closed script of definitions only waits for more text (real time).
pub const QUIET: Duration = Duration::from_millis(50);

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
        let read = if is_closed(&text) {
            // `None` when quiet: run what is there.
            tokio::time::timeout(QUIET, sock.read(&mut buf)).await.ok()
        } else {
            Some(sock.read(&mut buf).await)
        };
        let n = match read {
            None => {
                run(&text, shared);
                text.clear();
                continue;
            }
            Some(Ok(0) | Err(_)) => 0,
            Some(Ok(n)) => n,
        };
        if n > 0 {
            text.push_str(&String::from_utf8_lossy(&buf[..n]));
        }
        if n == 0 || is_complete(&text) {
            if !text.trim().is_empty() {
                run(&text, shared);
            }
            if n == 0 {
                return;
            }
            text.clear();
        }
    }
}

fn run(text: &str, shared: &Shared) {
    let now = shared.clock.now_ns();
    match Program::parse(text) {
        Ok(program) => shared.lock().upload(program, now),
        Err(e) => {
            tracing::error!("script refused, not started: {e}");
            shared.lock().refuse_upload(now);
        }
    }
}
