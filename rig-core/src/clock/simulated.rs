//! The state behind a simulated clock ([`Clock::scaled`](super::Clock::scaled),
//! [`Clock::governed`](super::Clock::governed)): the current stretch of time at one rate
//! ([`Segment`]), and the pacers the clock waits for, with the hold that starts when the
//! free-running time passes the slowest pacer's limit.

use std::time::Duration;

use tokio::time::Instant;

/// The state of a simulated clock: the current stretch at one rate, and the pacers it waits for.
#[derive(Debug)]
pub(super) struct SimState {
    pub(super) seg: Segment,
    /// The last time read: the clock never goes back, even when a pacer joins late.
    pub(super) last_ns: u64,
    pub(super) pacers: Vec<PacerSlot>,
    pub(super) next_id: u64,
    /// Whether the clock is holding now (its free-running time is past a pacer's limit).
    pub(super) holding: bool,
    pub(super) stats: HoldStats,
}

#[derive(Debug, Clone, Copy)]
pub(super) struct PacerSlot {
    pub(super) id: u64,
    pub(super) name: &'static str,
    pub(super) reached_ns: u64,
    pub(super) lead: Duration,
}

/// How often, and how long in real time, a simulated clock held for its pacers.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct HoldStats {
    /// Episodes of holding (a hold starts when the clock first reaches a pacer's limit).
    pub holds: u64,
    /// Real time spent holding, summed over the episodes (the one under way included).
    pub held_s: f64,
    /// The pacer that started the most recent hold.
    pub last_holder: Option<&'static str>,
    pub(super) started: Option<std::time::Instant>,
}

impl SimState {
    pub(super) fn new(factor: f64) -> Self {
        Self {
            seg: Segment {
                base: Instant::now(),
                base_ns: 0,
                factor,
            },
            last_ns: 0,
            pacers: Vec::new(),
            next_id: 0,
            holding: false,
            stats: HoldStats::default(),
        }
    }

    /// The latest time the pacers allow, and the pacer that sets it (`u64::MAX` with none).
    pub(super) fn limit(&self) -> (u64, Option<&'static str>) {
        let factor = self.seg.factor;
        self.pacers
            .iter()
            .map(|p| {
                let lead_ns = (p.lead.as_secs_f64() * factor * 1e9).min(1e18) as u64;
                (p.reached_ns.saturating_add(lead_ns), Some(p.name))
            })
            .min_by_key(|(t, _)| *t)
            .unwrap_or((u64::MAX, None))
    }

    /// The clock's time now. When the free-running time passes the pacers' limit the clock
    /// holds there: the stretch restarts at the limit, so time moves on from it (never jumps)
    /// once the pacers catch up.
    pub(super) fn now_ns(&mut self) -> u64 {
        let free = self.seg.now_ns();
        let (limit, holder) = self.limit();
        let t = if free > limit {
            let t = limit.max(self.last_ns);
            self.seg = Segment {
                base: Instant::now(),
                base_ns: t,
                factor: self.seg.factor,
            };
            if !self.holding {
                self.holding = true;
                self.stats.holds += 1;
                self.stats.last_holder = holder;
                self.stats.started = Some(std::time::Instant::now());
            }
            t
        } else {
            self.end_hold();
            free.max(self.last_ns)
        };
        self.last_ns = t;
        t
    }

    pub(super) fn end_hold(&mut self) {
        if self.holding {
            self.holding = false;
            if let Some(s) = self.stats.started.take() {
                self.stats.held_s += s.elapsed().as_secs_f64();
            }
        }
    }
}

/// A stretch of a governed clock at one rate: `t = base_ns + (now − base) · factor`.
#[derive(Debug, Clone, Copy)]
pub(super) struct Segment {
    pub(super) base: Instant,
    pub(super) base_ns: u64,
    pub(super) factor: f64,
}

impl Segment {
    pub(super) fn now_ns(&self) -> u64 {
        self.base_ns
            .saturating_add((self.base.elapsed().as_secs_f64() * self.factor * 1e9) as u64)
    }
    pub(super) fn deadline(&self, t_ns: u64) -> Instant {
        let ahead = t_ns.saturating_sub(self.base_ns) as f64 * 1e-9 / self.factor;
        self.base + Duration::from_secs_f64(ahead.min(1e9))
    }
}
