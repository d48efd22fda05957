//! Simulate once, render per sensor: the contact tapes of [`ContactCache`].
//!
//! The contact state of a press (wrench and surface field) depends on the indenter, the gel,
//! the contact physics and the path the indenter takes, not on the LEDs, markers or camera.
//! So the physics of one sensor's run is kept, one **tape** per contact episode (from the
//! first step in contact to the lift-off), in a cache directory keyed by everything the
//! physics depends on ([`cache_key`]: the elastomer config, the indenter's geometry, the
//! physics config and the physics' own source code). A later run of a sensor with the same
//! gel replays the tapes instead of solving: its camera renders its own optics from the
//! tape's surface fields, and the F/T twins read the tape's wrench. A sensor whose gel differs
//! (another modulus, thickness, relaxation) has another key and solves.
//!
//! # Replaying
//!
//! A replayed step is looked up by **where the indenter is**, not by when: the two runs'
//! motions follow the same plan, but their controller ticks, command latencies and so the
//! phase of the physics' 50 Hz grid differ by milliseconds, and the pause between two stages
//! by tens of them (host latency, multiplied by the scaled clock). At the first step in
//! contact, the candidates are the tapes that touched down at the same point (to
//! [`MATCH_MM`]). Each moving step then finds, on each candidate's polyline of step positions,
//! the point nearest to the indenter among those about as far along the path as the run has
//! come (path length; the way back of a slide passes the way out's places, further along),
//! within [`MATCH_MM`], and interpolates the wrench and the fields linearly between the two
//! recorded steps around it (they are 20 µm of travel apart at the plan's speeds, a twentieth of
//! a grid cell). Before the tape's first step and after its last the polyline runs on to the
//! undeformed surface (depth 0, no load), so a touch-down or lift-off between grid ticks is
//! covered. While the indenter rests, the step is found by the time since the rest began,
//! from where the tape came to rest (relaxation); a rest longer than the tape's extrapolates
//! its last two steps for at most [`MAX_REST_SLIP_NS`]. Candidates that share a path (the
//! plan's 12 directions share their way down) are kept until the path tells them apart.
//!
//! The physics has history (stick in the gel's material points, viscoelastic relaxation), so
//! time matters too: the tape's time at the found point, less the run's time since
//! touch-down, or where the last rest (the run's or the tape's) ended, by at most
//! [`MAX_REST_SLIP_NS`] (200 ms: a pause between two stages differs that much between two
//! runs at ×20 on a busy host; relaxation changes a force by about
//! (1 − 1/`instant_modulus_ratio`) · Δt / τ of it, at most 2.7 % at the shipped 1.25 and 1.5 s,
//! and less as it decays; the live physics' own answer moves by about 2 % at the cone's peak
//! when its steps fall elsewhere on the path. The test `contact_tape` measures both.)
//!
//! **A run that leaves the tapes solves live.** A pose off every candidate's path (a
//! protective stop, a retract, another plan), a rest longer than the tape's by more than the
//! slip allowed, or a drift past it ends the replay: the simulator's history is rebuilt by
//! solving every step of the episode so far at its own time and pose, and the episode goes on
//! live from there, exactly as if it had never been replayed. An episode solved live (from
//! touch-down, or rebuilt so) is written to the cache as a new tape when it lifts off (in the
//! background, to a temporary name, renamed when whole).
//!
//! # What a tape holds
//!
//! Per step: its time since touch-down, the indenter's position (contact point plus shear,
//! mm; depth, mm), the simulator's wrench (about the contact point) and, when the camera
//! needed it, the surface displacement field `uz, ux, uy` as `f32` on the box of cells where any
//! of them exceeds [`CROP_MM`] (zero outside; the renderer treats a cell as untouched below
//! 1 µm of height and 0.1 µm of shift, so nothing it draws is lost). Contact pressure and
//! tractions are not kept: no camera draws them.

use std::io;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use rig_core::config::ElastomerConfig;
use rig_core::indenter::Indenter;

use super::config::PhysicsConfig;
use super::lock::lock;

mod file;
mod replay;

pub use file::CROP_MM;
use file::{Tape, TapeRecorder};
pub(super) use replay::Episode;

/// A pose is on a tape's path when it is within this of the polyline of its steps' positions,
/// mm (1 µm: a straight `movel` stays on its line to rounding, and the arm stops at each
/// stage's end, so no step cuts a corner; where it stops depends on the controller tick its
/// move ends on, within about 0.7 µm of the target).
pub const MATCH_MM: f64 = 1e-3;
/// A pose repeated within this of the last move (an F/T read within a controller tick or two
/// of a step) is the same state, ns.
pub const MAX_DRIFT_NS: i64 = 5_000_000;
/// The most the run's timing may slip against the tape's since touch-down or the last rest
/// (the run's or the tape's), ns (see the module docs): the rig's pauses between stages are a
/// few controller ticks plus the host's latency, which the scaled clock multiplies (at ×20,
/// 5 ms of latency is 100 ms, and two runs' pauses were seen to differ by that much); 200 ms of
/// relaxation at the shipped 1.25 and 1.5 s is 2.7 % of a force.
pub const MAX_REST_SLIP_NS: i64 = 200_000_000;
/// How far the run's path length may be from the tape's at a found point, mm: the run's
/// steps cut no corner (the arm stops at each stage's end), so only rounding separates them.
const PATH_SLACK_MM: f64 = 5e-3;
/// Below this (mm) between two steps, the indenter rests.
const REST_MM: f64 = 1e-6;

/// FNV-1a, usable in a `const`.
const fn fnv1a(mut h: u64, bytes: &[u8]) -> u64 {
    let mut i = 0;
    while i < bytes.len() {
        h ^= bytes[i] as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
        i += 1;
    }
    h
}
const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;

/// The physics' own source: a tape made by other code is another key, so a change to the
/// solver never replays stale tapes.
const PHYSICS_SOURCE: u64 = {
    let mut h = FNV_OFFSET;
    h = fnv1a(h, include_bytes!("mod.rs"));
    h = fnv1a(h, include_bytes!("file.rs"));
    h = fnv1a(h, include_bytes!("replay.rs"));
    h = fnv1a(h, include_bytes!("../physics.rs"));
    h = fnv1a(h, include_bytes!("../read_ahead.rs"));
    h = fnv1a(h, include_bytes!("../../sim/mod.rs"));
    h = fnv1a(h, include_bytes!("../../sim/scene.rs"));
    h = fnv1a(h, include_bytes!("../../sim/contact/mod.rs"));
    h = fnv1a(h, include_bytes!("../../sim/contact/geometry.rs"));
    h = fnv1a(h, include_bytes!("../../sim/contact/normal.rs"));
    h = fnv1a(h, include_bytes!("../../sim/contact/tangential.rs"));
    h = fnv1a(h, include_bytes!("../../sim/contact/kernels.rs"));
    h = fnv1a(h, include_bytes!("../../sim/contact/window.rs"));
    h = fnv1a(h, include_bytes!("../../sim/contact/fft.rs"));
    h = fnv1a(
        h,
        include_bytes!("../../../../rig-core/src/indenter/mod.rs"),
    );
    h = fnv1a(
        h,
        include_bytes!("../../../../rig-core/src/indenter/shape.rs"),
    );
    h
};

/// The cache key of a physics: everything a contact state depends on, hashed (16 hex digits).
pub fn cache_key(
    elastomer: &ElastomerConfig,
    indenter: &Indenter,
    config: &PhysicsConfig,
) -> String {
    let mut h = PHYSICS_SOURCE;
    h = fnv1a(h, format!("{elastomer:?}").as_bytes());
    h = fnv1a(h, format!("{indenter:?}").as_bytes());
    let physics = format!(
        "{} {:?} {:?} {:?} {}",
        config.rate_hz, config.contact, config.cell_mm, config.friction, config.viscoelastic
    );
    h = fnv1a(h, physics.as_bytes());
    format!("{h:016x}")
}

/// The contact cache's counters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct TapeStats {
    /// Tapes the cache held when it was opened.
    pub tapes_found: u64,
    /// Steps in contact answered from a tape.
    pub replayed_steps: u64,
    /// Steps in contact solved (live episodes, and the steps re-solved after leaving a tape).
    pub solved_steps: u64,
    /// Episodes replayed from touch-down to lift-off.
    pub episodes_replayed: u64,
    /// Episodes that left their tapes and went on live.
    pub episodes_left: u64,
    /// Tapes written.
    pub tapes_written: u64,
}

/// A directory of contact tapes for one physics (see the module docs). Cheap to clone.
#[derive(Clone)]
pub struct ContactCache {
    inner: Arc<CacheInner>,
}

struct CacheInner {
    dir: PathBuf,
    tapes: Mutex<Vec<Arc<Tape>>>,
    next_id: AtomicU64,
    tapes_found: u64,
    replayed_steps: AtomicU64,
    solved_steps: AtomicU64,
    episodes_replayed: AtomicU64,
    episodes_left: AtomicU64,
    tapes_written: AtomicU64,
    /// Background writes still running.
    writers: Mutex<Vec<std::thread::JoinHandle<()>>>,
}

impl std::fmt::Debug for ContactCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ContactCache")
            .field("dir", &self.inner.dir)
            .field("stats", &self.stats())
            .finish()
    }
}

impl ContactCache {
    /// The cache of `root` for this physics: `root/<cache_key>/`, created if missing. Tapes
    /// already there are loaded (their step tables; fields are read when a replay needs them).
    /// A tape file that cannot be read is skipped with a warning.
    pub fn open(
        root: &Path,
        elastomer: &ElastomerConfig,
        indenter: &Indenter,
        config: &PhysicsConfig,
    ) -> io::Result<Self> {
        let dir = root.join(cache_key(elastomer, indenter, config));
        std::fs::create_dir_all(&dir)?;
        let mut tapes = Vec::new();
        let mut names: Vec<PathBuf> = std::fs::read_dir(&dir)?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|x| x == "tape"))
            .collect();
        names.sort();
        for path in names {
            match Tape::load(&path) {
                Ok(t) => tapes.push(Arc::new(t)),
                Err(e) => tracing::warn!("contact cache: skipping {}: {e}", path.display()),
            }
        }
        let found = tapes.len() as u64;
        Ok(Self {
            inner: Arc::new(CacheInner {
                dir,
                tapes: Mutex::new(tapes),
                next_id: AtomicU64::new(0),
                tapes_found: found,
                replayed_steps: AtomicU64::new(0),
                solved_steps: AtomicU64::new(0),
                episodes_replayed: AtomicU64::new(0),
                episodes_left: AtomicU64::new(0),
                tapes_written: AtomicU64::new(0),
                writers: Mutex::new(Vec::new()),
            }),
        })
    }

    /// Where this physics' tapes are.
    pub fn dir(&self) -> &Path {
        &self.inner.dir
    }

    pub fn stats(&self) -> TapeStats {
        let c = &self.inner;
        TapeStats {
            tapes_found: c.tapes_found,
            replayed_steps: c.replayed_steps.load(Ordering::Relaxed),
            solved_steps: c.solved_steps.load(Ordering::Relaxed),
            episodes_replayed: c.episodes_replayed.load(Ordering::Relaxed),
            episodes_left: c.episodes_left.load(Ordering::Relaxed),
            tapes_written: c.tapes_written.load(Ordering::Relaxed),
        }
    }

    /// Waits for the tapes being written.
    pub fn flush(&self) {
        let writers = std::mem::take(&mut *lock(&self.inner.writers));
        for w in writers {
            let _ = w.join();
        }
    }

    /// The tapes that touched down at the point of `at` (x, y), to [`MATCH_MM`].
    fn touching_down_at(&self, at: &[f64; 3]) -> Vec<Arc<Tape>> {
        lock(&self.inner.tapes)
            .iter()
            .filter(|t| {
                let p = t.steps[0].at;
                (p[0] - at[0]).hypot(p[1] - at[1]) <= MATCH_MM
            })
            .cloned()
            .collect()
    }

    /// Writes a live episode as a tape, in the background.
    fn store(&self, rec: TapeRecorder) {
        if rec.steps.is_empty() {
            return;
        }
        let id = self.inner.next_id.fetch_add(1, Ordering::Relaxed);
        let name = format!(
            "{}-{}-{id}.tape",
            std::process::id(),
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_nanos())
        );
        let path = self.inner.dir.join(name);
        let cache = self.clone();
        let handle = std::thread::spawn(move || match rec.write(&path) {
            Ok(()) => match Tape::load(&path) {
                Ok(t) => {
                    lock(&cache.inner.tapes).push(Arc::new(t));
                    cache.inner.tapes_written.fetch_add(1, Ordering::Relaxed);
                }
                Err(e) => tracing::warn!("contact cache: {}: {e}", path.display()),
            },
            Err(e) => tracing::warn!("contact cache: writing {}: {e}", path.display()),
        });
        let mut writers = lock(&self.inner.writers);
        writers.retain(|w| !w.is_finished());
        writers.push(handle);
    }
}
