//! A device's u32 sequence number (Net F/T `rdt_sequence`, DAQ frame sequence), tracked for
//! loss, reordering and duplicates, and unwrapped to a u64 that keeps counting across wraps.
//!
//! [`SequenceTracker::observe`] classifies every arriving number and keeps exact counts: a gap
//! adds its size to `lost`; a number that later fills a gap moves one from `lost` to
//! `reordered`; a number seen before is a duplicate. [`SequenceTracker::observe_unwrapped`]
//! also returns the number unwrapped against the newest one seen (the first arrives as itself,
//! a later one as the first plus how far it is ahead, a late one as how far it is behind), the
//! `device_seq` a front end stamps its samples with.

use super::SampleFlags;

/// How one arriving sequence number relates to those before it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Arrival {
    /// The first packet seen.
    First,
    /// The next one expected.
    InOrder,
    /// Newer than expected: `missing` packets in between are (for now) lost.
    AfterGap { missing: u32 },
    /// Older than the newest, filling an earlier gap: reordered, not lost.
    Late,
    /// Seen before, or too old to tell (beyond the tracking window).
    Duplicate,
}

impl Arrival {
    /// What a sample carried by this arrival is flagged with: [`SampleFlags::AFTER_GAP`] after
    /// a gap, [`SampleFlags::REORDERED`] when late, nothing otherwise; `None` for a duplicate,
    /// which a reader drops.
    pub fn sample_flags(self) -> Option<SampleFlags> {
        match self {
            Arrival::Duplicate => None,
            Arrival::AfterGap { .. } => Some(SampleFlags::AFTER_GAP),
            Arrival::Late => Some(SampleFlags::REORDERED),
            Arrival::First | Arrival::InOrder => Some(SampleFlags::NONE),
        }
    }
}

/// Exact loss / reorder / duplicate counts.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct SequenceStats {
    pub received: u64,
    pub lost: u64,
    pub reordered: u64,
    pub duplicates: u64,
    /// Gaps larger than [`MAX_TRACKED_GAP`] (counted in `lost` but not individually tracked).
    pub large_gaps: u64,
}

/// Largest gap whose missing sequence numbers are remembered individually (so a late packet
/// can be told from a duplicate). Larger jumps (a box restart) still count as lost.
pub const MAX_TRACKED_GAP: u32 = 4096;
/// How far behind the newest sequence a missing number is still remembered.
pub const TRACK_WINDOW: u32 = 1 << 16;

/// Kept above every unwrapped number internally (one u32 span), so that stepping back from the
/// first number seen never underflows.
const UNWRAP_OFFSET: u64 = 1 << 32;

/// Tracks a u32 sequence (wrapping) for loss and reordering. See the module docs.
#[derive(Debug, Clone, Default)]
pub struct SequenceTracker {
    newest: Option<u32>,
    missing: std::collections::BTreeSet<u64>,
    // Unwrapped counterpart of `newest` plus [`UNWRAP_OFFSET`], so that the missing set orders
    // correctly across wraps and a number from before the first one never goes below zero.
    newest_unwrapped: u64,
    stats: SequenceStats,
}

impl SequenceTracker {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn stats(&self) -> SequenceStats {
        self.stats
    }

    /// Classifies `seq` and updates the counts.
    pub fn observe(&mut self, seq: u32) -> Arrival {
        self.observe_unwrapped(seq).0
    }

    /// As [`Self::observe`], and `seq` unwrapped to a u64 against the newest number seen (see
    /// the module docs). Wraps only where the u32 arithmetic would: a number from before the
    /// first one seen, just below zero, comes out near `u64::MAX`.
    pub fn observe_unwrapped(&mut self, seq: u32) -> (Arrival, u64) {
        let (arrival, unwrapped) = self.classify(seq);
        (arrival, unwrapped.wrapping_sub(UNWRAP_OFFSET))
    }

    fn classify(&mut self, seq: u32) -> (Arrival, u64) {
        self.stats.received += 1;
        let Some(newest) = self.newest else {
            self.newest = Some(seq);
            self.newest_unwrapped = u64::from(seq) + UNWRAP_OFFSET;
            return (Arrival::First, self.newest_unwrapped);
        };
        let delta = seq.wrapping_sub(newest) as i32;
        if delta > 0 {
            let missing = (delta - 1) as u32;
            let base = self.newest_unwrapped;
            if missing > MAX_TRACKED_GAP {
                self.stats.large_gaps += 1;
            } else {
                for k in 1..=u64::from(missing) {
                    self.missing.insert(base + k);
                }
            }
            self.stats.lost += u64::from(missing);
            self.newest = Some(seq);
            self.newest_unwrapped = base + delta as u64;
            // Forget gaps too old to be filled.
            let horizon = self
                .newest_unwrapped
                .saturating_sub(u64::from(TRACK_WINDOW));
            while let Some(&first) = self.missing.first() {
                if first >= horizon {
                    break;
                }
                self.missing.pop_first();
            }
            let arrival = if missing == 0 {
                Arrival::InOrder
            } else {
                Arrival::AfterGap { missing }
            };
            (arrival, self.newest_unwrapped)
        } else if delta == 0 {
            self.stats.duplicates += 1;
            (Arrival::Duplicate, self.newest_unwrapped)
        } else {
            let back = u64::from(delta.unsigned_abs());
            let unwrapped = self.newest_unwrapped.saturating_sub(back);
            if self.missing.remove(&unwrapped) {
                self.stats.lost -= 1;
                self.stats.reordered += 1;
                (Arrival::Late, unwrapped)
            } else {
                self.stats.duplicates += 1;
                (Arrival::Duplicate, unwrapped)
            }
        }
    }
}
