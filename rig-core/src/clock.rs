//! One injectable clock for the rig and the mocks.
//!
//! Every component takes time from a [`Clock`] handle instead of calling `Instant::now()` or
//! `tokio::time::sleep` itself. Three kinds exist:
//!
//! - [`Clock::system`]: real monotonic time, for the lab rig.
//! - [`Clock::scaled`]: simulated time that runs `factor` times faster than real time, so the
//!   simulated rig (real sockets, real tasks) can finish a 240-trajectory plan in minutes.
//! - [`Clock::manual`]: time moves only when a test advances the returned [`ClockHandle`], so a
//!   test that steps time is deterministic.
//!
//! Time is a `u64` count of nanoseconds since the clock's epoch (its creation), named `t_ns`
//! throughout the code base. Device clocks (RTDE `timestamp`, F/T sequence counters, V4L2 buffer
//! stamps) are mapped onto this one by explicit estimators, never assumed equal to it.

use std::future::Future;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

// tokio's Instant reads std's monotonic clock, except under a paused tokio runtime, where it
// follows tokio's virtual time; using it keeps `now_ns` and the sleeps on one time base.
use tokio::time::Instant;

use tokio::sync::watch;

/// A cheap, cloneable handle on a shared clock.
#[derive(Clone, Debug)]
pub struct Clock {
    inner: Arc<Inner>,
}

#[derive(Debug)]
enum Inner {
    System {
        origin: Instant,
    },
    Scaled {
        origin: Instant,
        factor: f64,
    },
    Manual {
        now_ns: AtomicU64,
        tick: watch::Sender<u64>,
    },
    Governed {
        seg: std::sync::Mutex<Segment>,
        /// Bumped on every rate change, so sleepers recompute their deadlines.
        changed: watch::Sender<u64>,
    },
}

/// A stretch of a governed clock at one rate: `t = base_ns + (now − base) · factor`.
#[derive(Debug, Clone, Copy)]
struct Segment {
    base: Instant,
    base_ns: u64,
    factor: f64,
}

impl Segment {
    fn now_ns(&self) -> u64 {
        self.base_ns
            .saturating_add((self.base.elapsed().as_secs_f64() * self.factor * 1e9) as u64)
    }
    fn deadline(&self, t_ns: u64) -> Instant {
        let ahead = t_ns.saturating_sub(self.base_ns) as f64 * 1e-9 / self.factor;
        self.base + Duration::from_secs_f64(ahead.min(1e9))
    }
}

/// Advances a manual clock. Dropping it does not stop the clock's sleepers from being woken by
/// other handles; a clock with no handle left simply never moves again.
#[derive(Clone, Debug)]
pub struct ClockHandle {
    clock: Clock,
}

/// Error of [`Clock::timeout`]: the deadline passed before the future completed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("timed out after {0:?} of clock time")]
pub struct Elapsed(pub Duration);

impl Clock {
    /// Real monotonic time.
    pub fn system() -> Self {
        Self {
            inner: Arc::new(Inner::System {
                origin: Instant::now(),
            }),
        }
    }

    /// Simulated time running `factor` times as fast as real time (`factor` ≥ 1 runs faster).
    ///
    /// Panics if `factor` is not finite and positive: that is a programming error, not input.
    pub fn scaled(factor: f64) -> Self {
        assert!(
            factor.is_finite() && factor > 0.0,
            "clock scale factor must be finite and positive, got {factor}"
        );
        if factor == 1.0 {
            return Self::system();
        }
        Self {
            inner: Arc::new(Inner::Scaled {
                origin: Instant::now(),
                factor,
            }),
        }
    }

    /// Simulated time like [`Clock::scaled`], whose rate can be changed while it runs
    /// ([`Clock::set_rate`]): a governor slows it down when a simulated device cannot keep up,
    /// so every device still sees one consistent time. Time never jumps: a rate change only
    /// changes how fast it moves from now on. Sleepers wake at the right clock time across rate
    /// changes.
    ///
    /// Panics if `factor` is not finite and positive (a programming error).
    pub fn governed(factor: f64) -> Self {
        assert!(
            factor.is_finite() && factor > 0.0,
            "clock scale factor must be finite and positive, got {factor}"
        );
        let (changed, _) = watch::channel(0);
        Self {
            inner: Arc::new(Inner::Governed {
                seg: std::sync::Mutex::new(Segment {
                    base: Instant::now(),
                    base_ns: 0,
                    factor,
                }),
                changed,
            }),
        }
    }

    /// Changes the rate of a [`Clock::governed`] clock from now on; returns `false` (and does
    /// nothing) for any other clock or a rate that is not finite and positive.
    pub fn set_rate(&self, factor: f64) -> bool {
        let Inner::Governed { seg, changed } = &*self.inner else {
            return false;
        };
        if !(factor.is_finite() && factor > 0.0) {
            return false;
        }
        {
            let mut g = seg.lock().unwrap_or_else(|p| p.into_inner());
            let now = Instant::now();
            let t = g.now_ns();
            *g = Segment {
                base: now,
                base_ns: t,
                factor,
            };
        }
        changed.send_modify(|g| *g = g.wrapping_add(1));
        true
    }

    /// A clock that only moves when the returned handle advances it. It starts at `t_ns = 0`.
    pub fn manual() -> (Self, ClockHandle) {
        let (tick, _) = watch::channel(0);
        let clock = Self {
            inner: Arc::new(Inner::Manual {
                now_ns: AtomicU64::new(0),
                tick,
            }),
        };
        let handle = ClockHandle {
            clock: clock.clone(),
        };
        (clock, handle)
    }

    /// How many clock seconds pass per real second (1 for the system clock; undefined, reported
    /// as infinity, for a manual clock).
    pub fn rate(&self) -> f64 {
        match &*self.inner {
            Inner::System { .. } => 1.0,
            Inner::Scaled { factor, .. } => *factor,
            Inner::Manual { .. } => f64::INFINITY,
            Inner::Governed { seg, .. } => seg.lock().unwrap_or_else(|p| p.into_inner()).factor,
        }
    }

    /// Nanoseconds since the clock's epoch.
    pub fn now_ns(&self) -> u64 {
        match &*self.inner {
            Inner::System { origin } => saturating_ns(origin.elapsed()),
            Inner::Scaled { origin, factor } => {
                let real = origin.elapsed().as_secs_f64();
                (real * factor * 1e9) as u64
            }
            Inner::Manual { now_ns, .. } => now_ns.load(Ordering::Acquire),
            Inner::Governed { seg, .. } => seg.lock().unwrap_or_else(|p| p.into_inner()).now_ns(),
        }
    }

    /// Time since the clock's epoch.
    pub fn now(&self) -> Duration {
        Duration::from_nanos(self.now_ns())
    }

    /// Seconds since the clock's epoch, as `f64`.
    pub fn now_s(&self) -> f64 {
        self.now_ns() as f64 * 1e-9
    }

    /// Sleep until the clock reads at least `t_ns`.
    pub async fn sleep_until_ns(&self, t_ns: u64) {
        match &*self.inner {
            Inner::System { origin } => {
                tokio::time::sleep_until(*origin + Duration::from_nanos(t_ns)).await;
            }
            Inner::Scaled { origin, factor } => {
                let real = Duration::from_secs_f64(t_ns as f64 * 1e-9 / factor);
                tokio::time::sleep_until(*origin + real).await;
            }
            Inner::Manual { tick, .. } => {
                let mut rx = tick.subscribe();
                // `wait_for` checks the current value first, so an already-passed deadline
                // returns at once. The sender lives in `self`, so the channel never closes here.
                let _ = rx.wait_for(|now| *now >= t_ns).await;
            }
            Inner::Governed { seg, changed } => {
                let mut rx = changed.subscribe();
                loop {
                    // Subscribed before reading the segment: a change after this is seen.
                    rx.borrow_and_update();
                    let (now, deadline) = {
                        let g = seg.lock().unwrap_or_else(|p| p.into_inner());
                        (g.now_ns(), g.deadline(t_ns))
                    };
                    if now >= t_ns {
                        return;
                    }
                    tokio::select! {
                        _ = tokio::time::sleep_until(deadline) => {}
                        // The sender lives in `self`: the channel never closes here.
                        _ = rx.changed() => {}
                    }
                }
            }
        }
    }

    /// Sleep for `d` of clock time.
    pub async fn sleep(&self, d: Duration) {
        let deadline = self.now_ns().saturating_add(saturating_ns(d));
        self.sleep_until_ns(deadline).await;
    }

    /// Run `fut` with a deadline of `d` clock time.
    pub async fn timeout<F: Future>(&self, d: Duration, fut: F) -> Result<F::Output, Elapsed> {
        tokio::select! {
            out = fut => Ok(out),
            _ = self.sleep(d) => Err(Elapsed(d)),
        }
    }

    /// A ticker with absolute deadlines every `period` of clock time, starting one period from
    /// now. Late ticks do not accumulate drift: deadline k is `start + k · period`.
    pub fn ticker(&self, period: Duration) -> Ticker {
        let period_ns = saturating_ns(period).max(1);
        Ticker {
            clock: self.clone(),
            next_ns: self.now_ns().saturating_add(period_ns),
            period_ns,
        }
    }
}

impl ClockHandle {
    /// The clock this handle moves.
    pub fn clock(&self) -> &Clock {
        &self.clock
    }

    /// Move time forward by `d`, waking every sleeper whose deadline has passed.
    pub fn advance(&self, d: Duration) {
        let Inner::Manual { now_ns, tick } = &*self.clock.inner else {
            unreachable!("a ClockHandle is only made by Clock::manual");
        };
        let new = now_ns
            .fetch_add(saturating_ns(d), Ordering::AcqRel)
            .saturating_add(saturating_ns(d));
        tick.send_replace(new);
    }

    /// Set the time to `t_ns` if that is later than now (time never goes backwards).
    pub fn advance_to_ns(&self, t_ns: u64) {
        let now = self.clock.now_ns();
        if t_ns > now {
            self.advance(Duration::from_nanos(t_ns - now));
        }
    }
}

/// Absolute-deadline ticker made by [`Clock::ticker`].
#[derive(Debug)]
pub struct Ticker {
    clock: Clock,
    next_ns: u64,
    period_ns: u64,
}

impl Ticker {
    /// Wait for the next deadline and return it (in clock nanoseconds). When the caller fell
    /// behind by more than one period, the missed deadlines are skipped, not replayed in a burst.
    pub async fn tick(&mut self) -> u64 {
        self.clock.sleep_until_ns(self.next_ns).await;
        let due = self.next_ns;
        let now = self.clock.now_ns();
        let behind = now.saturating_sub(due) / self.period_ns;
        self.next_ns = due + (behind + 1) * self.period_ns;
        due
    }

    /// The ticker's period in nanoseconds.
    pub fn period_ns(&self) -> u64 {
        self.period_ns
    }
}

fn saturating_ns(d: Duration) -> u64 {
    u64::try_from(d.as_nanos()).unwrap_or(u64::MAX)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn manual_clock_moves_only_when_advanced_and_wakes_sleepers() {
        let (clock, handle) = Clock::manual();
        assert_eq!(clock.now_ns(), 0);
        let c2 = clock.clone();
        let sleeper = tokio::spawn(async move {
            c2.sleep(Duration::from_millis(10)).await;
            c2.now_ns()
        });
        tokio::task::yield_now().await;
        handle.advance(Duration::from_millis(4));
        tokio::task::yield_now().await;
        assert!(!sleeper.is_finished(), "woke before its deadline");
        handle.advance(Duration::from_millis(6));
        assert_eq!(sleeper.await.unwrap(), 10_000_000);
    }

    #[tokio::test]
    async fn manual_clock_never_goes_backwards() {
        let (clock, handle) = Clock::manual();
        handle.advance_to_ns(500);
        handle.advance_to_ns(100);
        assert_eq!(clock.now_ns(), 500);
    }

    #[tokio::test]
    async fn timeout_fires_on_clock_time() {
        let (clock, handle) = Clock::manual();
        let c2 = clock.clone();
        let task = tokio::spawn(async move {
            c2.timeout(Duration::from_secs(1), std::future::pending::<()>())
                .await
        });
        tokio::task::yield_now().await;
        handle.advance(Duration::from_secs(2));
        assert_eq!(task.await.unwrap(), Err(Elapsed(Duration::from_secs(1))));
    }

    #[tokio::test]
    async fn ticker_keeps_absolute_deadlines_and_skips_missed_ones() {
        let (clock, handle) = Clock::manual();
        let mut ticker = clock.ticker(Duration::from_millis(2));
        handle.advance(Duration::from_millis(2));
        assert_eq!(ticker.tick().await, 2_000_000);
        // Fall 3 periods behind: the next tick returns the overdue deadline once, then resumes
        // on the grid after "now" rather than replaying 4, 6, 8.
        handle.advance(Duration::from_millis(7)); // now = 9 ms
        assert_eq!(ticker.tick().await, 4_000_000);
        handle.advance(Duration::from_millis(1)); // now = 10 ms
        assert_eq!(ticker.tick().await, 10_000_000);
    }

    #[tokio::test(start_paused = true)]
    async fn scaled_clock_runs_faster_than_real_time() {
        let clock = Clock::scaled(10.0);
        let t0 = clock.now_ns();
        let real0 = tokio::time::Instant::now();
        clock.sleep(Duration::from_secs(1)).await;
        let real = real0.elapsed();
        // One clock second is 100 ms of (paused, auto-advanced) tokio time.
        assert!(
            real >= Duration::from_millis(100) && real < Duration::from_millis(101),
            "{real:?}"
        );
        let dt = clock.now_ns() - t0;
        assert!((1_000_000_000..1_010_000_000).contains(&dt), "{dt}");
    }

    #[tokio::test]
    async fn governed_clock_sleepers_wake_at_their_clock_time_across_rate_changes() {
        let clock = Clock::governed(200.0);
        let target = 2_000_000_000; // 2 s of clock time = 10 ms real at ×200
        let c2 = clock.clone();
        let sleeper = tokio::spawn(async move {
            c2.sleep_until_ns(target).await;
            c2.now_ns()
        });
        tokio::time::sleep(Duration::from_millis(2)).await;
        // Slower: a deadline computed at ×200 would now fire long before 2 s of clock time.
        assert!(clock.set_rate(20.0));
        let before = clock.now_ns();
        assert!(
            before < target,
            "the first 2 ms of real time passed {before} ns"
        );
        let woke = sleeper.await.unwrap();
        assert!(
            woke >= target,
            "woke at {woke} ns, before its deadline {target}"
        );
        assert_eq!(clock.rate(), 20.0);

        // Faster while sleeping: still wakes, at or after its deadline.
        let c3 = clock.clone();
        let t2 = clock.now_ns() + 500_000_000;
        let sleeper = tokio::spawn(async move {
            c3.sleep_until_ns(t2).await;
            c3.now_ns()
        });
        tokio::time::sleep(Duration::from_millis(1)).await;
        assert!(clock.set_rate(1000.0));
        assert!(sleeper.await.unwrap() >= t2);
    }

    #[test]
    fn governed_clock_never_jumps_or_goes_backwards_on_rate_changes() {
        let clock = Clock::governed(50.0);
        let mut last = clock.now_ns();
        for k in 0..200 {
            let r = if k % 2 == 0 { 0.5 } else { 80.0 };
            assert!(clock.set_rate(r));
            let now = clock.now_ns();
            assert!(now >= last, "time went back from {last} to {now}");
            last = now;
        }
        assert!(!clock.set_rate(f64::NAN));
        assert!(!clock.set_rate(0.0));
        assert!(!Clock::scaled(2.0).set_rate(3.0), "a fixed clock refuses");
    }
}
