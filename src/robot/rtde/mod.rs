//! Async RTDE client: handshake, typed streaming, input writes and reconnection.
//!
//! RTDE (UR's "Real-Time Data Exchange (RTDE) Guide", TCP port 30004) is a request/reply
//! handshake followed by a one-way stream: the client asks for protocol v2 (falling back to
//! v1, which CB3 software before 3.5 speaks), reads the controller version, sets up one output
//! recipe (the variables it wants, at a frequency: up to 500 Hz on e-Series, 125 Hz on CB3)
//! and its input recipes (the registers it will write), then sends Start. From then on the
//! controller sends a data package every cycle and accepts input data packages at any time.
//!
//! The code is split the way tokio's mini-redis splits a protocol, one layer a file, each
//! using only the layers listed before it:
//!
//! - `error.rs`: [`RtdeError`], whose messages say what the operator should check; every
//!   layer returns it.
//! - `session.rs`: [`Session`] is the handshake and stream as a sans-IO state machine: it is
//!   fed whole frames, queues the packages to send ([`Session::poll_transmit`]) and the things
//!   that happened ([`Session::poll_event`]). It never touches a socket or a clock (the
//!   handshake and stall timeouts belong to the connection), so each handshake corner (text
//!   messages mid-handshake, data before the Start reply, NOT_FOUND, IN_USE, a v1-only
//!   controller) is a plain unit test (`tests.rs`).
//! - `connection.rs`: [`FrameReader`] / [`FrameWriter`] own the two halves of the socket and
//!   turn bytes into frames and packages into bytes ([`rig_core::rtde::FrameDecoder`] does the
//!   cutting, so reads that split or coalesce packages do not matter). One reader task owns
//!   the read half and the session: it decodes every data package into a
//!   [`RobotState`](crate::robot::RobotState), publishes the latest one on a `watch` channel
//!   and every one on a bounded `broadcast` (for logging), and, when the link fails,
//!   reconnects with bounded retries and backoff on the shared clock, sending the recipes
//!   again (RTDE forgets them with the connection, and refuses connections while the
//!   controller reboots).
//! - `client.rs`: [`RtdeClient`], what the rest of the rig holds, starts the reader task and
//!   reads what it publishes; writes go through [`RtdeHandle`], which shares the current write
//!   half behind a mutex.
//!
//! Bad input never panics. A size field below 3 means the stream is out of sync: the
//! connection is dropped and re-made. A frame of an unknown type, or one that is truncated or
//! too long for its type, is counted ([`RtdeStats`]) and skipped. Text messages are logged
//! with `tracing` at their level, and the last few are kept for error reports.

mod client;
mod connection;
mod error;
mod session;
#[cfg(test)]
mod tests;

pub use client::{RtdeClient, RtdeHandle};
pub use connection::{
    Connection, FrameReader, FrameWriter, KEPT_TEXT_MESSAGES, LinkStatus, RtdeConfig, RtdeStats,
};
pub use error::{RecipeKind, RtdeError};
pub use session::{
    CB3_HZ, ControllerVersion, E_SERIES_HZ, Phase, Session, SessionConfig, SessionEvent, SkipReason,
};
