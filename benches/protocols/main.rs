//! Protocol benchmarks in one bench binary: `cargo bench --bench protocols` (add `-- rtde` or
//! `-- ft` to run one group's criterion cases).
//!
//! - [`rtde`]: decode time of one 500 Hz RTDE package, and the end-to-end latency from the
//!   simulated controller's sample to the client's typed state.
//! - [`ft`]: parse throughput of each F/T front end against the real device's rate.

use criterion::Criterion;

mod ft;
mod rtde;

fn main() {
    // `cargo test --benches` runs benches in test mode: keep that quick.
    let quick = std::env::args().any(|a| a == "--test");
    rtde::latency_table(if quick { 200 } else { 2000 });
    rtde::benches();
    ft::benches();
    Criterion::default().configure_from_args().final_summary();
    ft::summary();
}
