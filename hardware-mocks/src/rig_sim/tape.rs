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

use std::fs::File;
use std::io::{self, Read, Write};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use rig_core::config::ElastomerConfig;
use rig_core::indenter::Indenter;
use rig_core::wrench::Wrench;

use super::PhysicsConfig;
use crate::sim::{IndenterPose, Scene, SimError, SimOutput, Simulator, SurfaceField};

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
/// Field values below this (mm) are not kept (see the module docs).
pub const CROP_MM: f64 = 1e-5;
/// Below this (mm) between two steps, the indenter rests.
const REST_MM: f64 = 1e-6;
const MAGIC: &[u8; 8] = b"RIGTAPE1";
/// Bytes of one step's record in a tape file.
const STEP_BYTES: usize = 8 + 3 * 8 + 6 * 8 + 8 + 4;

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
    h = fnv1a(h, include_bytes!("tape.rs"));
    h = fnv1a(h, include_bytes!("physics.rs"));
    h = fnv1a(h, include_bytes!("../sim/mod.rs"));
    h = fnv1a(h, include_bytes!("../sim/scene.rs"));
    h = fnv1a(h, include_bytes!("../sim/contact/mod.rs"));
    h = fnv1a(h, include_bytes!("../sim/contact/normal.rs"));
    h = fnv1a(h, include_bytes!("../sim/contact/tangential.rs"));
    h = fnv1a(h, include_bytes!("../sim/contact/kernels.rs"));
    h = fnv1a(h, include_bytes!("../sim/contact/window.rs"));
    h = fnv1a(h, include_bytes!("../sim/contact/fft.rs"));
    h = fnv1a(h, include_bytes!("../../../rig-core/src/indenter/mod.rs"));
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
        let writers = std::mem::take(&mut *super::physics::lock(&self.inner.writers));
        for w in writers {
            let _ = w.join();
        }
    }

    /// The tapes that touched down at the point of `at` (x, y), to [`MATCH_MM`].
    fn touching_down_at(&self, at: &[f64; 3]) -> Vec<Arc<Tape>> {
        super::physics::lock(&self.inner.tapes)
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
                    super::physics::lock(&cache.inner.tapes).push(Arc::new(t));
                    cache.inner.tapes_written.fetch_add(1, Ordering::Relaxed);
                }
                Err(e) => tracing::warn!("contact cache: {}: {e}", path.display()),
            },
            Err(e) => tracing::warn!("contact cache: writing {}: {e}", path.display()),
        });
        let mut writers = super::physics::lock(&self.inner.writers);
        writers.retain(|w| !w.is_finished());
        writers.push(handle);
    }
}

/// One recorded step.
#[derive(Debug, Clone, Copy)]
struct TapeStep {
    /// Clock time since the episode's first step, ns.
    t_ns: u64,
    /// Indenter position: axis x, y and depth, mm.
    at: [f64; 3],
    /// The simulator's wrench (about the contact point), Fx..Mz.
    w: [f64; 6],
    /// Offset and length of the step's field in the file (length 0: none).
    field: (u64, u32),
}

/// A tape on disk: its step table in memory, its fields read when needed.
struct Tape {
    steps: Vec<TapeStep>,
    file: File,
    /// The last field decoded (replays read each field for several steps).
    decoded: Mutex<Option<(usize, Arc<SurfaceField>)>>,
}

impl Tape {
    fn load(path: &Path) -> io::Result<Tape> {
        let mut file = File::open(path)?;
        let mut head = [0u8; 12];
        file.read_exact(&mut head)?;
        if &head[..8] != MAGIC {
            return Err(bad("not a contact tape"));
        }
        let n = u32::from_le_bytes(head[8..12].try_into().expect("4 bytes")) as usize;
        if n == 0 || n > 10_000_000 {
            return Err(bad("implausible step count"));
        }
        let mut table = vec![0u8; n * STEP_BYTES];
        file.read_exact(&mut table)?;
        let len = file.metadata()?.len();
        let steps = table
            .chunks_exact(STEP_BYTES)
            .map(|c| {
                let mut r = Reader(c);
                let t_ns = r.u64();
                let at = [r.f64(), r.f64(), r.f64()];
                let w = std::array::from_fn(|_| r.f64());
                let field = (r.u64(), r.u32());
                TapeStep { t_ns, at, w, field }
            })
            .collect::<Vec<_>>();
        for s in &steps {
            let finite = s.at.iter().chain(&s.w).all(|v| v.is_finite());
            if !finite || s.field.0 + s.field.1 as u64 > len {
                return Err(bad("damaged step table"));
            }
        }
        Ok(Tape {
            steps,
            file,
            decoded: Mutex::new(None),
        })
    }

    fn has_fields(&self) -> bool {
        self.steps.iter().all(|s| s.field.1 > 0)
    }

    /// The field of step `k` (`None`: the step kept none).
    fn field(&self, k: usize) -> io::Result<Option<Arc<SurfaceField>>> {
        let (off, len) = self.steps[k].field;
        if len == 0 {
            return Ok(None);
        }
        let mut memo = super::physics::lock(&self.decoded);
        if let Some((i, f)) = memo.as_ref()
            && *i == k
        {
            return Ok(Some(f.clone()));
        }
        let mut buf = vec![0u8; len as usize];
        self.file.read_exact_at(&mut buf, off)?;
        let f = Arc::new(decode_field(&buf)?);
        *memo = Some((k, f.clone()));
        Ok(Some(f))
    }
}

/// A live episode being recorded.
struct TapeRecorder {
    steps: Vec<TapeStep>,
    fields: Vec<u8>,
}

impl TapeRecorder {
    fn push(&mut self, t_ns: u64, at: [f64; 3], out: &SimOutput) {
        let field = match &out.field {
            Some(f) => {
                let off = self.fields.len() as u64;
                encode_field(f, &mut self.fields);
                (off, (self.fields.len() as u64 - off) as u32)
            }
            None => (0, 0),
        };
        self.steps.push(TapeStep {
            t_ns,
            at,
            w: out.wrench.to_array(),
            field,
        });
    }

    fn write(&self, path: &Path) -> io::Result<()> {
        let base = (12 + self.steps.len() * STEP_BYTES) as u64;
        let mut out = Vec::with_capacity(base as usize + self.fields.len());
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&(self.steps.len() as u32).to_le_bytes());
        for s in &self.steps {
            out.extend_from_slice(&s.t_ns.to_le_bytes());
            for v in s.at.iter().chain(&s.w) {
                out.extend_from_slice(&v.to_le_bytes());
            }
            let off = if s.field.1 > 0 { base + s.field.0 } else { 0 };
            out.extend_from_slice(&off.to_le_bytes());
            out.extend_from_slice(&s.field.1.to_le_bytes());
        }
        out.extend_from_slice(&self.fields);
        let tmp = path.with_extension("tape.partial");
        let mut f = File::create(&tmp)?;
        f.write_all(&out)?;
        drop(f);
        std::fs::rename(&tmp, path)
    }
}

/// `nx, ny` (u32), `cell, origin x, origin y` (f64), the kept box `i0, j0, w, h` (u32), then
/// `uz, ux, uy` of each kept cell (f32, row by row).
fn encode_field(f: &SurfaceField, out: &mut Vec<u8>) {
    let (nx, ny) = (f.nx, f.ny);
    let (mut i0, mut i1, mut j0, mut j1) = (usize::MAX, 0, usize::MAX, 0);
    for j in 0..ny {
        for i in 0..nx {
            let k = j * nx + i;
            let big = [f.uz_mm[k], f.ux_mm[k], f.uy_mm[k]]
                .iter()
                .any(|v| v.abs() > CROP_MM);
            if big {
                (i0, i1, j0, j1) = (i0.min(i), i1.max(i), j0.min(j), j1.max(j));
            }
        }
    }
    let (w, h) = if i0 == usize::MAX {
        (i0, j0) = (0, 0);
        (0, 0)
    } else {
        (i1 + 1 - i0, j1 + 1 - j0)
    };
    for v in [nx, ny] {
        out.extend_from_slice(&(v as u32).to_le_bytes());
    }
    for v in [f.cell_mm, f.origin_mm[0], f.origin_mm[1]] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    for v in [i0, j0, w, h] {
        out.extend_from_slice(&(v as u32).to_le_bytes());
    }
    for j in j0..j0 + h {
        for i in i0..i0 + w {
            let k = j * nx + i;
            for v in [f.uz_mm[k], f.ux_mm[k], f.uy_mm[k]] {
                out.extend_from_slice(&(v as f32).to_le_bytes());
            }
        }
    }
}

fn decode_field(buf: &[u8]) -> io::Result<SurfaceField> {
    if buf.len() < 8 + 24 + 16 {
        return Err(bad("short field"));
    }
    let mut r = Reader(buf);
    let (nx, ny) = (r.u32() as usize, r.u32() as usize);
    let (cell_mm, ox, oy) = (r.f64(), r.f64(), r.f64());
    let (i0, j0, w, h) = (
        r.u32() as usize,
        r.u32() as usize,
        r.u32() as usize,
        r.u32() as usize,
    );
    if nx.checked_mul(ny).is_none_or(|n| n > 1 << 26)
        || i0 + w > nx
        || j0 + h > ny
        || r.0.len() != w * h * 12
    {
        return Err(bad("damaged field"));
    }
    let mut f = SurfaceField::unloaded(nx, ny, cell_mm, [ox, oy]);
    for j in j0..j0 + h {
        for i in i0..i0 + w {
            let k = j * nx + i;
            f.uz_mm[k] = r.f32() as f64;
            f.ux_mm[k] = r.f32() as f64;
            f.uy_mm[k] = r.f32() as f64;
        }
    }
    Ok(f)
}

struct Reader<'a>(&'a [u8]);

impl Reader<'_> {
    fn take<const N: usize>(&mut self) -> [u8; N] {
        let (a, b) = self.0.split_at(N);
        self.0 = b;
        a.try_into().expect("N bytes")
    }
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.take())
    }
    fn u64(&mut self) -> u64 {
        u64::from_le_bytes(self.take())
    }
    fn f32(&mut self) -> f32 {
        f32::from_le_bytes(self.take())
    }
    fn f64(&mut self) -> f64 {
        f64::from_le_bytes(self.take())
    }
}

fn bad(msg: &str) -> io::Error {
    io::Error::new(io::ErrorKind::InvalidData, msg)
}

/// `a + s (b − a)` of two fields on the same grid (`None`: the unloaded gel).
fn blend(a: Option<&SurfaceField>, b: Option<&SurfaceField>, s: f64) -> Option<SurfaceField> {
    let (ka, kb) = (1.0 - s, s);
    let mix = |x: Option<&Vec<f64>>, y: Option<&Vec<f64>>, n: usize| -> Vec<f64> {
        (0..n)
            .map(|k| ka * x.map_or(0.0, |v| v[k]) + kb * y.map_or(0.0, |v| v[k]))
            .collect()
    };
    let g = a.or(b)?;
    if let (Some(a), Some(b)) = (a, b)
        && (a.nx, a.ny) != (b.nx, b.ny)
    {
        return Some(if s < 0.5 { a.clone() } else { b.clone() });
    }
    let n = g.nx * g.ny;
    // (Not `..SurfaceField::unloaded(..)`: that would allocate three grids to drop, on every
    // replayed step.)
    Some(SurfaceField {
        nx: g.nx,
        ny: g.ny,
        cell_mm: g.cell_mm,
        origin_mm: g.origin_mm,
        uz_mm: mix(a.map(|f| &f.uz_mm), b.map(|f| &f.uz_mm), n),
        ux_mm: mix(a.map(|f| &f.ux_mm), b.map(|f| &f.ux_mm), n),
        uy_mm: mix(a.map(|f| &f.uy_mm), b.map(|f| &f.uy_mm), n),
        pressure_mpa: vec![0.0; n],
        traction_x_mpa: vec![0.0; n],
        traction_y_mpa: vec![0.0; n],
    })
}

/// Where a replay stands on one candidate tape.
struct Cursor {
    tape: Arc<Tape>,
    /// The polyline's vertex the last step was found at or after: 0 is the virtual touch-down
    /// point on the surface, `k + 1` the tape's step `k`, `len + 1` the virtual lift-off point.
    vertex: usize,
    /// Path length from the touch-down point to each vertex, mm.
    length: Vec<f64>,
    /// How far along the tape's path the run's last step was found, mm.
    path_mm: f64,
    /// Tape time less run time since touch-down, at the first step found on a real segment.
    offset_ns: Option<i64>,
    /// Where the run's last step was found.
    found: Option<Found>,
    /// The run's rest under way: its start (run time) and the tape's time there.
    rest: Option<(u64, i64)>,
}

/// A found point on a tape: between vertices `v` and `v + 1`, a fraction `s` of the way.
#[derive(Debug, Clone, Copy)]
struct Found {
    v: usize,
    s: f64,
}

fn dist(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt()
}

impl Cursor {
    fn new(tape: Arc<Tape>) -> Self {
        let mut c = Cursor {
            tape,
            vertex: 0,
            length: Vec::new(),
            path_mm: 0.0,
            offset_ns: None,
            found: None,
            rest: None,
        };
        let mut l = 0.0;
        c.length.push(0.0);
        for v in 1..c.n_vertices() {
            l += dist(&c.at(v - 1), &c.at(v));
            c.length.push(l);
        }
        c
    }

    fn n_vertices(&self) -> usize {
        self.tape.steps.len() + 2
    }

    /// Vertex `v`'s position (the virtual ends at depth 0 above the first and last steps).
    fn at(&self, v: usize) -> [f64; 3] {
        let steps = &self.tape.steps;
        if v == 0 {
            let p = steps[0].at;
            [p[0], p[1], 0.0]
        } else if v > steps.len() {
            let p = steps[steps.len() - 1].at;
            [p[0], p[1], 0.0]
        } else {
            steps[v - 1].at
        }
    }

    /// Vertex `v`'s tape time (`None` for the virtual ends).
    fn t(&self, v: usize) -> Option<i64> {
        (1..=self.tape.steps.len())
            .contains(&v)
            .then(|| self.tape.steps[v - 1].t_ns as i64)
    }

    /// The tape's time at a found point (`None` on a virtual segment).
    fn time_of(&self, f: Found) -> Option<i64> {
        let (ta, tb) = (self.t(f.v)?, self.t(f.v + 1)?);
        Some(ta + (f.s * (tb - ta) as f64) as i64)
    }

    /// Whether the tape rested at vertex `v` (the step before is at the same place).
    fn rests_at(&self, v: usize) -> bool {
        (2..=self.tape.steps.len()).contains(&v) && dist(&self.at(v - 1), &self.at(v)) <= REST_MM
    }

    /// Finds the run's moving step, `moved_mm` on from its last, at `at`, run time `t_rel`:
    /// the point of the tape's path nearest to `at` (within [`MATCH_MM`]) among those about
    /// as far along it as the run has come (the way back of a slide passes the way out's
    /// places, but further along), and the tape's time there within [`MAX_REST_SLIP_NS`] of
    /// the run's (less the offset at touch-down).
    fn find_moving(&mut self, moved_mm: f64, at: &[f64; 3], t_rel: u64) -> Option<Found> {
        let run_rested = self.rest.take().is_some();
        let path_mm = self.path_mm + moved_mm;
        let n = self.n_vertices();
        let mut best: Option<(f64, f64, Found)> = None;
        let mut v = self.vertex;
        while v + 1 < n && self.length[v] <= path_mm + PATH_SLACK_MM {
            let (la, lb) = (self.length[v], self.length[v + 1]);
            if lb >= path_mm - PATH_SLACK_MM {
                let (a, b) = (self.at(v), self.at(v + 1));
                let d: [f64; 3] = std::array::from_fn(|k| b[k] - a[k]);
                let dd: f64 = d.iter().map(|x| x * x).sum();
                let s = if dd <= REST_MM * REST_MM {
                    0.0
                } else {
                    ((0..3).map(|k| (at[k] - a[k]) * d[k]).sum::<f64>() / dd).clamp(0.0, 1.0)
                };
                let p: [f64; 3] = std::array::from_fn(|k| a[k] + s * d[k]);
                let l = la + s * (lb - la);
                let miss = (l - path_mm).abs();
                if dist(&p, at) <= MATCH_MM && best.is_none_or(|(m, _, _)| miss < m - 1e-9) {
                    best = Some((miss, l, Found { v, s }));
                }
            }
            v += 1;
        }
        let (_, l, found) = best?;
        // A rest of the run's or of the tape's just ended.
        let after_rest = run_rested || self.rests_at(found.v);
        if let Some(tape_t) = self.time_of(found) {
            let offset = tape_t - t_rel as i64;
            match self.offset_ns {
                Some(o) if (offset - o).abs() > MAX_REST_SLIP_NS => return None,
                // Set at the first step on the tape, and again where a rest ends (the rest's
                // length is the stage's pause, which the host's latency sets).
                Some(_) if !after_rest => {}
                _ => self.offset_ns = Some(offset),
            }
        }
        // Along the tape's own path from here: rounding never adds up.
        self.path_mm = l;
        self.vertex = found.v;
        Some(found)
    }

    /// Finds the run's resting step by time: the time since the run came to rest, from where
    /// the tape came to rest at the same place; past the tape's rest (a rest longer than the
    /// tape's), its last two steps are extrapolated (relaxation) for at most
    /// [`MAX_REST_SLIP_NS`].
    fn find_resting(&mut self, at: &[f64; 3], t_rel: u64, rest_start: u64) -> Option<Found> {
        let n = self.tape.steps.len();
        let near = |c: &Cursor, v: usize| dist(&c.at(v), at) <= MATCH_MM;
        // The tape's first real vertex at this place: the end of the segment the run was
        // last found on, or its start.
        let (start_v, start_t) = match self.rest {
            Some((_, t)) => (self.vertex, t),
            None => {
                let f = self.found?;
                let v = if f.s > 0.5 { f.v + 1 } else { f.v };
                if !(1..=n).contains(&v) || !near(self, v) {
                    // Where the tape moved on: the same state within a controller tick or
                    // two (an F/T read just after a step, at the same pose), else the run
                    // stopped where the tape did not (a protective stop).
                    return (t_rel - rest_start <= MAX_DRIFT_NS as u64).then_some(f);
                }
                let t = self.t(v)?;
                self.rest = Some((rest_start, t));
                (v, t)
            }
        };
        let tape_t = start_t + (t_rel - rest_start) as i64;
        let mut v = start_v;
        while v < n && near(self, v + 1) && self.t(v + 1)? <= tape_t {
            v += 1;
        }
        self.vertex = v;
        let t = |v: usize| self.t(v).expect("a real vertex");
        if v < n && near(self, v + 1) {
            let s = (tape_t - t(v)) as f64 / (t(v + 1) - t(v)).max(1) as f64;
            return Some(Found {
                v,
                s: s.clamp(0.0, 1.0),
            });
        }
        // The tape's rest here ends at vertex v (or it never rested here).
        let past = tape_t - t(v);
        if past > MAX_REST_SLIP_NS {
            return None;
        }
        if past > 0 && v >= 2 && near(self, v - 1) {
            let s = 1.0 + past as f64 / (t(v) - t(v - 1)).max(1) as f64;
            return Some(Found { v: v - 1, s });
        }
        Some(Found { v, s: 0.0 })
    }

    /// The wrench and field at a found point.
    fn state(&self, f: Found, want_field: bool) -> io::Result<(Wrench, Option<Arc<SurfaceField>>)> {
        let n = self.tape.steps.len();
        let w_of = |v: usize| -> [f64; 6] {
            if (1..=n).contains(&v) {
                self.tape.steps[v - 1].w
            } else {
                [0.0; 6]
            }
        };
        let (wa, wb) = (w_of(f.v), w_of(f.v + 1));
        let w = Wrench::from_array(std::array::from_fn(|k| wa[k] + f.s * (wb[k] - wa[k])));
        if !want_field {
            return Ok((w, None));
        }
        let field_of = |v: usize| -> io::Result<Option<Arc<SurfaceField>>> {
            if (1..=n).contains(&v) {
                self.tape.field(v - 1)
            } else {
                Ok(None)
            }
        };
        let field = if f.s == 0.0 {
            field_of(f.v)?
        } else if f.s == 1.0 {
            field_of(f.v + 1)?
        } else {
            let (a, b) = (field_of(f.v)?, field_of(f.v + 1)?);
            blend(a.as_deref(), b.as_deref(), f.s).map(Arc::new)
        };
        // An unloaded end: a flat field on the tape's grid.
        let field = match field {
            Some(f) => Some(f),
            None => blend(field_of(1.min(n))?.as_deref(), None, 1.0).map(Arc::new),
        };
        Ok((w, field))
    }
}

/// The indenter's position as a tape keeps it: axis x, y and depth, mm.
fn position(p: &IndenterPose) -> [f64; 3] {
    [
        p.contact_mm[0] + p.shear_mm[0],
        p.contact_mm[1] + p.shear_mm[1],
        p.depth_mm,
    ]
}

/// What the physics does with one contact episode: replays it from tapes while it can, else
/// solves live (see the module docs).
pub(super) struct Episode {
    cache: Option<ContactCache>,
    /// Every step of the episode so far: its time and pose (to rebuild the history on leaving
    /// the tapes).
    log: Vec<(u64, IndenterPose)>,
    /// The candidates still on the run's path; empty once live.
    cursors: Vec<Cursor>,
    /// Recording this episode (solved live from its first step).
    recorder: Option<TapeRecorder>,
    /// The previous step's position (rest detection).
    last_at: Option<[f64; 3]>,
    /// Run time (since touch-down) of the last step that moved: where a rest began.
    rest_start: u64,
    replaying: bool,
}

impl Episode {
    pub(super) fn new(cache: Option<ContactCache>) -> Self {
        Self {
            cache,
            log: Vec::new(),
            cursors: Vec::new(),
            recorder: None,
            last_at: None,
            rest_start: 0,
            replaying: false,
        }
    }

    pub(super) fn cache(&self) -> Option<&ContactCache> {
        self.cache.as_ref()
    }

    /// One step in contact at clock time `t_ns`: the simulator's wrench (about the contact
    /// point) and field, from the tapes or solved on `sim`.
    pub(super) fn step(
        &mut self,
        sim: &mut Simulator,
        scene: &Scene,
        t_ns: u64,
        want_field: bool,
    ) -> Result<(Wrench, Option<SurfaceField>, Option<Arc<SurfaceField>>), SimError> {
        let at = position(&scene.pose);
        if self.log.is_empty() {
            self.cursors = self.cache.as_ref().map_or_else(Vec::new, |c| {
                c.touching_down_at(&at)
                    .into_iter()
                    .filter(|t| !want_field || t.has_fields())
                    .map(Cursor::new)
                    .collect()
            });
            self.replaying = !self.cursors.is_empty();
            self.recorder = (self.cache.is_some() && !self.replaying).then(|| TapeRecorder {
                steps: Vec::new(),
                fields: Vec::new(),
            });
        }
        let t0 = self.log.first().map_or(t_ns, |(t, _)| *t);
        let t_rel = t_ns - t0;
        self.log.push((t_ns, scene.pose));
        let moved = self.last_at.map_or(at[2], |q| dist(&q, &at));
        let resting = self.last_at.is_some() && moved <= REST_MM;
        if !resting {
            self.rest_start = t_rel;
        }
        self.last_at = Some(at);
        if self.replaying {
            let rest_start = self.rest_start;
            // Where the candidates stood, for the log of a replay that leaves them (built
            // only when that log is on).
            let before: Option<Vec<String>> = tracing::enabled!(tracing::Level::DEBUG).then(|| {
                self.cursors
                    .iter()
                    .map(|c| {
                        let around: Vec<String> = (c.vertex.saturating_sub(2)
                            ..(c.vertex + 5).min(c.n_vertices()))
                            .map(|v| {
                                format!("{v}: {:?} L {:.5} t {:?}", c.at(v), c.length[v], c.t(v))
                            })
                            .collect();
                        format!(
                            "vertex {} offset {:?} path {:.5} rest {:?} [{}]",
                            c.vertex,
                            c.offset_ns,
                            c.path_mm,
                            c.rest,
                            around.join("; ")
                        )
                    })
                    .collect()
            });
            self.cursors.retain_mut(|c| {
                let found = if resting {
                    c.find_resting(&at, t_rel, rest_start)
                } else {
                    c.find_moving(moved, &at, t_rel)
                };
                c.found = found;
                found.is_some()
            });
            if let Some(c) = self.cursors.first() {
                let found = c.found.expect("kept cursors found the pose");
                match c.state(found, want_field) {
                    Ok((w, field)) => {
                        if let Some(cache) = &self.cache {
                            cache.inner.replayed_steps.fetch_add(1, Ordering::Relaxed);
                        }
                        return Ok((w, None, field));
                    }
                    Err(e) => tracing::warn!("contact cache: reading a tape: {e}"),
                }
            }
            // Off every tape: rebuild the history live, then go on live.
            tracing::debug!(
                "contact cache: left the tapes at {at:?}, {t_rel} ns after touch-down (resting: \
                 {resting}; candidates' vertex and offset before: {before:?})"
            );
            self.replaying = false;
            self.cursors.clear();
            if let Some(cache) = &self.cache {
                cache.inner.episodes_left.fetch_add(1, Ordering::Relaxed);
            }
            // The rebuilt steps are this run's own live solution: recorded as a tape.
            sim.reset();
            self.recorder = self.cache.as_ref().map(|_| TapeRecorder {
                steps: Vec::new(),
                fields: Vec::new(),
            });
            let n = self.log.len();
            for (t, pose) in &self.log[..n - 1] {
                let mut s = scene.clone();
                s.pose = *pose;
                let out = sim.step(&s, *t as f64 * 1e-9)?;
                self.count_solved();
                if let Some(rec) = &mut self.recorder {
                    rec.push(t - t0, position(pose), &out);
                }
            }
        }
        let out = sim.step(scene, t_ns as f64 * 1e-9)?;
        self.count_solved();
        if let Some(rec) = &mut self.recorder {
            rec.push(t_rel, at, &out);
        }
        Ok((out.wrench, out.field, None))
    }

    fn count_solved(&self) {
        if let Some(cache) = &self.cache {
            cache.inner.solved_steps.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// The episode ended (the indenter left the gel): a live one becomes a tape.
    pub(super) fn end(&mut self) {
        if self.log.is_empty() {
            return;
        }
        if let Some(cache) = &self.cache {
            if self.replaying {
                cache
                    .inner
                    .episodes_replayed
                    .fetch_add(1, Ordering::Relaxed);
            }
            if let Some(rec) = self.recorder.take() {
                cache.store(rec);
            }
        }
        self.log.clear();
        self.cursors.clear();
        self.recorder = None;
        self.last_at = None;
        self.rest_start = 0;
        self.replaying = false;
    }
}
