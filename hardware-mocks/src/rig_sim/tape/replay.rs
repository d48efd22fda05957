//! Replaying tapes: following the run's indenter along the candidate tapes, and leaving them
//! for the live physics (see the module docs of `tape`).

use std::io;
use std::sync::Arc;
use std::sync::atomic::Ordering;

use rig_core::wrench::Wrench;

use super::file::{Tape, TapeRecorder, blend};
use super::{ContactCache, MATCH_MM, MAX_DRIFT_NS, MAX_REST_SLIP_NS, PATH_SLACK_MM, REST_MM};
use crate::sim::{History, IndenterPose, Scene, SimError, Simulator, SurfaceField};

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

/// A contact step's result: the simulator's wrench (about the contact point), and the surface
/// field either as solved (owned) or as replayed from a tape (shared).
pub(in crate::rig_sim) type StepOut = (Wrench, Option<SurfaceField>, Option<Arc<SurfaceField>>);

/// What the physics does with one contact episode: replays it from tapes while it can, else
/// solves live (see the module docs).
pub(in crate::rig_sim) struct Episode {
    cache: Option<ContactCache>,
    /// Clock time of the episode's first step (`None`: no episode under way).
    t0: Option<u64>,
    /// Every step of the episode so far while it is replayed: its time and pose (to rebuild the
    /// history on leaving the tapes; a live episode keeps none).
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
    pub(in crate::rig_sim) fn new(cache: Option<ContactCache>) -> Self {
        Self {
            cache,
            t0: None,
            log: Vec::new(),
            cursors: Vec::new(),
            recorder: None,
            last_at: None,
            rest_start: 0,
            replaying: false,
        }
    }

    pub(in crate::rig_sim) fn cache(&self) -> Option<&ContactCache> {
        self.cache.as_ref()
    }

    /// One step in contact at clock time `t_ns`: the simulator's wrench (about the contact
    /// point) and field, from the tapes or solved on `sim`.
    pub(in crate::rig_sim) fn step(
        &mut self,
        sim: &mut Simulator,
        scene: &Scene,
        t_ns: u64,
        want_field: bool,
    ) -> Result<StepOut, SimError> {
        let at = position(&scene.pose);
        if self.t0.is_none() {
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
        let t0 = *self.t0.get_or_insert(t_ns);
        let t_rel = t_ns - t0;
        if self.replaying {
            self.log.push((t_ns, scene.pose));
        }
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

    /// A step at `t_ns` from the history `from` (`None`: the simulator's own) that leaves the
    /// episode and the simulator's history as they were ([`Simulator::probe`]). While the
    /// episode replays tapes, or has not begun and tapes could start it, it is a
    /// [`Self::step`]: a replayed step is found by where the indenter is, so asking it between
    /// the grid's steps moves nothing.
    pub(in crate::rig_sim) fn probe(
        &mut self,
        sim: &mut Simulator,
        from: Option<&History>,
        scene: &Scene,
        t_ns: u64,
        want_field: bool,
    ) -> Result<StepOut, SimError> {
        if self.replaying || (self.t0.is_none() && self.cache.is_some()) {
            return self.step(sim, scene, t_ns, want_field);
        }
        let out = sim.probe(from, scene, t_ns as f64 * 1e-9)?;
        Ok((out.wrench, out.field, None))
    }

    fn count_solved(&self) {
        if let Some(cache) = &self.cache {
            cache.inner.solved_steps.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// The episode ended (the indenter left the gel): a live one becomes a tape.
    pub(in crate::rig_sim) fn end(&mut self) {
        if self.t0.take().is_none() {
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
