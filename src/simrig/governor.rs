//! The clock governor of a simulated run.

use std::time::Duration;

use rig_core::clock::Clock;

/// Keeps the simulated clock as fast as the simulated camera can follow, up to `max`: the
/// camera renders each frame after its capture time, so when rendering falls behind, the clock
/// slows down (every simulated device follows it) and frames stay on time; when it catches up,
/// the clock speeds up again. Lag is measured in frame periods between the clock and the
/// newest frame handed to the recording, which `newest_frame_ns` reads (0: none yet).
pub async fn govern(
    clock: Clock,
    max: f64,
    newest_frame_ns: impl Fn() -> u64 + Send + 'static,
    period_ns: f64,
) {
    let floor = max.min(0.25);
    let mut rate = clock.rate();
    let mut last_stamp = 0;
    let mut last_advance = std::time::Instant::now();
    loop {
        // Real time: the governor watches the machine, not the simulation.
        tokio::time::sleep(Duration::from_millis(20)).await;
        let newest = newest_frame_ns();
        if newest == 0 {
            continue;
        }
        if newest != last_stamp {
            last_stamp = newest;
            last_advance = std::time::Instant::now();
        } else if last_advance.elapsed() > Duration::from_millis(300) {
            // No frame for a long real time is not slowness but a stalled camera: the stall
            // watch handles that, and slowing the clock would only delay its verdict.
            continue;
        }
        let lag = clock.now_ns().saturating_sub(newest) as f64 / period_ns;
        // Up to about 6 frames in the pipeline (two renders in flight, each behind a contact
        // solve, then encoding) is throughput, not falling behind.
        let next = if lag > 12.0 {
            rate * 0.6
        } else if lag > 8.0 {
            rate * 0.9
        } else if lag < 6.0 {
            rate * 1.05
        } else {
            rate
        }
        .clamp(floor, max);
        if (next - rate).abs() > 1e-6 * max {
            clock.set_rate(next);
            rate = next;
        }
    }
}
