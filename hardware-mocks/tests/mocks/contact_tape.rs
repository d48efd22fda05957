//! Simulate once, render per sensor: a second run of the same gel, indenter and motion replays
//! the first run's contact tapes instead of solving, and gives the contact the live physics
//! would give at its own poses and times; a run that leaves the tapes solves live, exactly.
//!
//! The runs drive [`ContactPhysics::update`] directly along a press of the plan's shape (down
//! at 1 mm/s, a rest, a 2 mm slide at 2 mm/s, a rest, back, up) on the physics' 50 Hz grid,
//! with the off-grid steps the F/T twins ask for at stage starts. The replaying run's motion
//! starts 7.3 ms later on the grid than the recording's and rests 80 ms longer at the end of
//! its slide, as two runs of the rig do: its grid samples other poses than the tape has.

use std::path::Path;
use std::sync::Arc;

use hardware_mocks::rig_sim::{ContactCache, ContactPhysics, PhysicsConfig, pose_above_surface};
use hardware_mocks::sim::SurfaceField;
use rig_core::config::{ElastomerConfig, RigConfig};
use rig_core::indenter::Indenter;
use rig_core::pose::Pose;
use rig_core::wrench::Wrench;

const DEPTH_MM: f64 = 0.8;
const SLIDE_MM: f64 = 2.0;
const GRID_NS: u64 = 20_000_000;

/// A press of the plan's shape, starting `delay_ns` after clock 0, with `extra_rest_ns` more
/// rest after the slide; `stop_at_s`: the arm stops there (a protective stop) and retracts
/// straight up instead of finishing.
#[derive(Clone, Copy)]
struct Press {
    angle_deg: f64,
    delay_ns: u64,
    extra_rest_ns: u64,
    stop_at_s: Option<f64>,
}

impl Press {
    fn new(angle_deg: f64) -> Self {
        Self {
            angle_deg,
            delay_ns: 0,
            extra_rest_ns: 0,
            stop_at_s: None,
        }
    }

    /// Stage boundaries, s: start (0.1 mm above the gel), touch, bottom, rest end, slid, rest
    /// end, back, rest end, up (0.1 mm above).
    fn stages(&self) -> [f64; 9] {
        let extra = self.extra_rest_ns as f64 * 1e-9;
        let down = (DEPTH_MM + 0.1) / 1.0;
        let slide = SLIDE_MM / 2.0;
        let mut t = [0.0; 9];
        let durations = [
            0.1,
            down - 0.1,
            0.04,
            slide,
            0.04 + extra,
            slide,
            0.04,
            down,
        ];
        for k in 0..8 {
            t[k + 1] = t[k] + durations[k];
        }
        t
    }

    /// The indenter's (x, y, depth) at clock time `t_ns`, mm.
    fn at(&self, t_ns: u64) -> [f64; 3] {
        let t = (t_ns as f64 - self.delay_ns as f64) * 1e-9;
        let (dx, dy) = {
            let a = self.angle_deg.to_radians();
            (a.cos(), a.sin())
        };
        let st = self.stages();
        let depth_down = |t: f64| -0.1 + t.clamp(0.0, st[2]) * 1.0;
        let slid = |t: f64| -> f64 {
            if t < st[3] {
                0.0
            } else if t < st[4] {
                (t - st[3]) * 2.0
            } else if t < st[5] {
                SLIDE_MM
            } else if t < st[6] {
                SLIDE_MM - (t - st[5]) * 2.0
            } else {
                0.0
            }
        };
        if let Some(stop) = self.stop_at_s
            && t > stop
        {
            // Stopped where it was, then up at 1 mm/s after 0.2 s.
            let s = slid(stop);
            let lift = (t - stop - 0.2).max(0.0);
            return [1.0 + s * dx, -0.5 + s * dy, DEPTH_MM - lift];
        }
        let depth = if t <= st[7] {
            depth_down(t)
        } else {
            DEPTH_MM - (t - st[7])
        };
        let s = slid(t);
        [1.0 + s * dx, -0.5 + s * dy, depth]
    }

    /// The step times: the 50 Hz grid, plus a step 1 ms after each stage start (as the F/T
    /// twins ask for where the motion leaves the line), to well after lift-off.
    fn times(&self) -> Vec<u64> {
        self.times_every(GRID_NS)
    }

    /// [`Press::times`] on a grid of `grid_ns`.
    fn times_every(&self, grid_ns: u64) -> Vec<u64> {
        let end = self.delay_ns + ((self.stages()[8] + 0.5) * 1e9) as u64;
        let mut t: Vec<u64> = (0..=end / grid_ns).map(|k| k * grid_ns).collect();
        for s in self.stages() {
            t.push(self.delay_ns + (s * 1e9) as u64 + 1_000_000);
        }
        if let Some(s) = self.stop_at_s {
            t.push(self.delay_ns + (s * 1e9) as u64 + 1_000_000);
        }
        t.sort_unstable();
        t.dedup();
        t
    }
}

fn cone() -> Arc<Indenter> {
    Arc::new(Indenter::builtin("cone").unwrap())
}

fn physics(cache: Option<ContactCache>, elastomer: &ElastomerConfig) -> ContactPhysics {
    ContactPhysics::with_cache(
        Pose::default(),
        elastomer.clone(),
        cone(),
        PhysicsConfig::default(),
        true,
        cache,
    )
    .unwrap()
}

fn open(root: &Path, elastomer: &ElastomerConfig) -> ContactCache {
    ContactCache::open(root, elastomer, &cone(), &PhysicsConfig::default()).unwrap()
}

/// One step's result: time, position, wrench and (in contact) the field.
struct Step {
    t_ns: u64,
    at: [f64; 3],
    w: Wrench,
    field: Option<Arc<SurfaceField>>,
}

/// Runs `press` through `physics`, one step per time.
fn run(physics: &ContactPhysics, press: &Press) -> Vec<Step> {
    run_at(physics, press, press.times())
}

/// Runs `press` through `physics`, one step at each of `times`.
fn run_at(physics: &ContactPhysics, press: &Press, times: Vec<u64>) -> Vec<Step> {
    times
        .into_iter()
        .map(|t| {
            let at = press.at(t);
            let tcp = pose_above_surface(&Pose::default(), at[0], at[1], -at[2]);
            let w = physics.update(t, &tcp).unwrap();
            let field = (at[2] > 0.0)
                .then(|| physics.latest_field().map(|(_, f)| f))
                .flatten();
            Step {
                t_ns: t,
                at,
                w,
                field,
            }
        })
        .collect()
}

fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

#[test]
fn a_second_run_with_the_same_gel_replays_the_tape_and_gets_the_live_contact() {
    let dir = tempfile::tempdir().unwrap();
    let gel = RigConfig::sim_source().elastomer;
    let first = Press::new(30.0);
    let cache = open(dir.path(), &gel);
    let recorded = run(&physics(Some(cache.clone()), &gel), &first);
    cache.flush();
    let s = cache.stats();
    assert_eq!(
        (s.tapes_found, s.tapes_written, s.replayed_steps),
        (0, 1, 0)
    );
    let contact_steps = recorded.iter().filter(|s| s.at[2] > 0.0).count() as u64;
    assert_eq!(s.solved_steps, contact_steps);

    // The second sensor's run: the same gel, another phase of the grid, a rest 80 ms longer
    // (two runs' pauses between stages differ by that much at ×20).
    let second = Press {
        delay_ns: 7_300_000,
        extra_rest_ns: 80_000_000,
        ..first
    };
    let cache = open(dir.path(), &gel);
    let replayed = run(&physics(Some(cache.clone()), &gel), &second);
    let live = run(&physics(None, &gel), &second);
    cache.flush();
    let s = cache.stats();
    let contact_steps = live.iter().filter(|s| s.at[2] > 0.0).count() as u64;
    assert_eq!(s.tapes_found, 1);
    assert_eq!(
        (
            s.replayed_steps,
            s.solved_steps,
            s.episodes_replayed,
            s.episodes_left
        ),
        (contact_steps, 0, 1, 0),
        "{s:?}"
    );
    assert_eq!(
        s.tapes_written, 0,
        "a replayed episode is not written again"
    );

    // The replayed wrench against the live one at the same poses and times.
    let peak_fz = live.iter().map(|s| -s.w.force_n[2]).fold(0.0, f64::max);
    let peak_ft = live
        .iter()
        .map(|s| s.w.force_n[0].hypot(s.w.force_n[1]))
        .fold(0.0, f64::max);
    assert!(peak_fz > 0.3 && peak_ft > 0.1, "{peak_fz} {peak_ft}");
    let mut worst = [0.0f64; 3];
    for (r, l) in replayed.iter().zip(&live) {
        assert_eq!(r.t_ns, l.t_ns);
        for (k, w) in worst.iter_mut().enumerate() {
            *w = w.max((r.w.force_n[k] - l.w.force_n[k]).abs());
        }
        if std::env::var_os("TAPE_DEBUG").is_some() {
            eprintln!(
                "DBG {:8.1} {:?} live {:?} replay {:?}",
                r.t_ns as f64 * 1e-6,
                r.at,
                l.w.force_n,
                r.w.force_n
            );
        }
    }
    eprintln!("peak |Fz| {peak_fz:.4} N, |Ft| {peak_ft:.4} N; worst replay error {worst:?} N");
    // The live physics' own dependence on where its steps fall: the same motion stepped on a
    // grid twice as fine, at the replay's step times.
    let fine = run_at(
        &physics(None, &gel),
        &second,
        second.times_every(GRID_NS / 2),
    );
    let mut own = [0.0f64; 3];
    for l in &live {
        let f = fine
            .iter()
            .find(|f| f.t_ns == l.t_ns)
            .expect("a common time");
        for (k, o) in own.iter_mut().enumerate() {
            *o = o.max((f.w.force_n[k] - l.w.force_n[k]).abs());
        }
    }
    eprintln!("the live physics at 50 Hz against 100 Hz: worst {own:?} N");
    // The replay reads the tape between steps 20 µm apart and 3 ms out of step in time; the
    // live physics itself moves by more than that when its steps fall elsewhere (incremental
    // friction follows the slip path step by step): the replay is as good as the live physics.
    for k in 0..3 {
        assert!(
            worst[k] <= own[k] && worst[k] <= 0.02 * peak_fz,
            "axis {k}: replay {worst:?}, the live physics' own {own:?}, peak {peak_fz} N"
        );
    }

    // The fields the camera renders, against the live ones and against the live physics' own
    // dependence on its grid (cell by cell, the largest difference over the press).
    let field_diff = |a: &SurfaceField, b: &SurfaceField| -> [f64; 2] {
        assert_eq!((a.nx, a.ny), (b.nx, b.ny));
        [
            max_abs_diff(&a.uz_mm, &b.uz_mm),
            max_abs_diff(&a.ux_mm, &b.ux_mm).max(max_abs_diff(&a.uy_mm, &b.uy_mm)),
        ]
    };
    let (mut rep, mut own, mut compared) = ([0.0f64; 2], [0.0f64; 2], 0);
    for (r, l) in replayed.iter().zip(&live) {
        if let (Some(a), Some(b)) = (&r.field, &l.field) {
            let f = fine
                .iter()
                .find(|f| f.t_ns == l.t_ns)
                .expect("a common time");
            let c = f.field.as_ref().expect("in contact");
            let (d, o) = (field_diff(a, b), field_diff(c, b));
            for k in 0..2 {
                rep[k] = rep[k].max(d[k]);
                own[k] = own[k].max(o[k]);
            }
            compared += 1;
        }
    }
    eprintln!(
        "{compared} fields; largest |Δuz|, |Δut| (mm): replay {rep:?}, the live physics' own {own:?}"
    );
    assert!(compared as u64 >= contact_steps - 1, "{compared}");
    assert!(rep[0] <= own[0] && rep[1] <= own[1], "{rep:?} {own:?}");
}

#[test]
fn a_run_that_leaves_the_tape_goes_on_live_exactly() {
    let dir = tempfile::tempdir().unwrap();
    let gel = RigConfig::sim_source().elastomer;
    let plan = Press::new(120.0);
    let cache = open(dir.path(), &gel);
    run(&physics(Some(cache.clone()), &gel), &plan);
    cache.flush();

    // A protective stop half-way through the slide, then a retract straight up.
    let stop_at = plan.stages()[3] + 0.5;
    let stopped = Press {
        delay_ns: 4_100_000,
        stop_at_s: Some(stop_at),
        ..plan
    };
    let cache = open(dir.path(), &gel);
    let replayed = run(&physics(Some(cache.clone()), &gel), &stopped);
    let live = run(&physics(None, &gel), &stopped);
    cache.flush();
    let s = cache.stats();
    assert_eq!((s.episodes_replayed, s.episodes_left), (0, 1), "{s:?}");
    assert!(s.replayed_steps > 20, "replayed up to the stop: {s:?}");
    // The episode's history was solved anew at the run's own poses: a tape of its own.
    assert_eq!(s.tapes_written, 1, "{s:?}");
    // After the stop the history was rebuilt live: the wrench is the live physics', exactly.
    let after = stopped.delay_ns + ((stop_at + 0.25) * 1e9) as u64;
    let mut checked = 0;
    for (r, l) in replayed.iter().zip(&live) {
        if r.t_ns >= after && l.at[2] > 0.0 {
            assert_eq!(r.w, l.w, "at {} ns", r.t_ns);
            checked += 1;
        }
    }
    assert!(checked > 5, "{checked}");
}

#[test]
fn another_gel_or_physics_has_its_own_tapes_and_a_damaged_tape_is_skipped() {
    let dir = tempfile::tempdir().unwrap();
    let gel = RigConfig::sim_source().elastomer;
    let cache = open(dir.path(), &gel);
    run(&physics(Some(cache.clone()), &gel), &Press::new(0.0));
    cache.flush();
    assert_eq!(cache.stats().tapes_written, 1);

    // The target sensor's gel (5 % stiffer): another key, nothing to replay; it solves.
    let target = RigConfig::sim_target().elastomer;
    assert_ne!(gel, target);
    let other = open(dir.path(), &target);
    assert_ne!(other.dir(), cache.dir());
    run(&physics(Some(other.clone()), &target), &Press::new(0.0));
    other.flush();
    let s = other.stats();
    assert_eq!(
        (s.tapes_found, s.replayed_steps, s.tapes_written),
        (0, 0, 1)
    );
    assert!(s.solved_steps > 50);
    // Winkler on the same gel: another key too.
    let winkler = PhysicsConfig {
        contact: hardware_mocks::sim::ContactModel::Winkler,
        ..PhysicsConfig::default()
    };
    let w = ContactCache::open(dir.path(), &gel, &cone(), &winkler).unwrap();
    assert_eq!(w.stats().tapes_found, 0);

    // A damaged file among the tapes: skipped, the good tape still replays.
    std::fs::write(cache.dir().join("junk.tape"), b"RIGTAPE1\x05\0\0\0short").unwrap();
    let again = open(dir.path(), &gel);
    assert_eq!(again.stats().tapes_found, 1);
    run(&physics(Some(again.clone()), &gel), &Press::new(0.0));
    assert_eq!(again.stats().solved_steps, 0, "{:?}", again.stats());
}
