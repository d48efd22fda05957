//! The F/T's read-ahead on the simulated rig: the buffer of physics steps ([`Sample`]), and how
//! a wrench is read off the line through its last steps for a time past the newest one
//! ([`read_off_line`], [`along`]), or found to need a solve ([`Ahead`]). Pure functions of the
//! buffer, so their decisions are tested here without a simulator; `physics.rs` steps the
//! contact and calls them.

use std::collections::VecDeque;

use rig_core::wrench::Wrench;

use crate::sim::IndenterPose;

/// One physics step in the buffer: the pose time, the wrench, and where the indenter was (its
/// axis in the surface frame and its depth, mm; the depth is negative out of contact).
#[derive(Debug, Clone, Copy)]
pub(super) struct Sample {
    pub(super) t_ns: u64,
    pub(super) w: Wrench,
    pub(super) at_mm: [f64; 3],
    /// The grid tick whose starting history the solve began from: its own time for a step on
    /// the grid, the nearest tick's for a probe between ticks (`ContactPhysics::step_at`). A
    /// step does not leave a history that gives its own force back, so two solves at one pose
    /// from different starts differ (up to 0.14 N where paralines slides): a reading is
    /// anchored only on a solve from its own start, and takes a slope only from two solves
    /// from one start.
    pub(super) start_ns: u64,
}

/// The indenter's position in the surface frame as a [`Sample`] stores it.
pub(super) fn position(p: &IndenterPose) -> [f64; 3] {
    [
        p.contact_mm[0] + p.shear_mm[0],
        p.contact_mm[1] + p.shear_mm[1],
        p.depth_mm,
    ]
}

/// Motion below this (mm) is rest: the simulated UR5e holds its pose exactly when stopped.
const REST_MM: f64 = 1e-6;
/// A pose further than this (mm) off the line through the last two steps' poses has changed
/// direction (a stage start); a straight `movel` stays on it to rounding.
const OFF_LINE_MM: f64 = 1e-4;
/// How far past the newest step, in units of the last two steps' spacing, a pose may be read
/// off their line: the error of that linear reading grows with the distance, and the solver's
/// own noise in the difference of the two steps is multiplied by it.
pub(super) const MAX_LINE_STEPS: f64 = 2.0;
/// How far past the newest step (mm of travel) a pose may be read off the line at most,
/// whatever the steps' spacing: the linear reading's error grows with the square of it.
pub(super) const MAX_LINE_MM: f64 = 0.005;
/// The least length of the line's baseline (mm), where the steps allow it.
const MIN_BASE_MM: f64 = MAX_LINE_MM / 2.0;

/// What `ContactPhysics::read_ahead` can say about a time past the newest step.
pub(super) enum Ahead {
    /// The wrench, read off the motion's line (or zero out of contact).
    Wrench(Wrench),
    /// The buffer answers: the time is covered, or the indenter rests and only relaxation
    /// changes the wrench (extrapolated in time).
    Buffer,
    /// The motion left the line of the last two steps: solve at the sample's pose.
    Solve,
}

/// `a + s·(b − a)`: between `a` and `b` for `s ∈ [0, 1]`; past `b` (`s > 1`) an extrapolation
/// that never goes past the unloaded gel (pressing gives Fz < 0: extrapolating an unloading
/// past zero is lift-off, and an unloaded `b` stays unloaded).
pub(super) fn along(a: &Wrench, b: &Wrench, s: f64) -> Wrench {
    let (a, b) = (a.to_array(), b.to_array());
    let out: [f64; 6] = std::array::from_fn(|k| a[k] + s * (b[k] - a[k]));
    if s > 1.0 && (b[2] < 0.0 && out[2] >= 0.0 || b[2] == 0.0) {
        return if b[2] == 0.0 {
            Wrench::from_array(b)
        } else {
            Wrench::default()
        };
    }
    Wrench::from_array(out)
}

/// Past the newest step while the indenter rests: the wrench extrapolated in time (relaxation)
/// along the newest step and one at least `half_period_ns` before it, up to twice their
/// spacing on. When that earlier step began from another start (see [`Sample::start_ns`]), the
/// slope is taken from it and an earlier step of its own start, and laid from the newest step:
/// the difference between two starts is a jump, not a relaxation. The newest wrench is held
/// when no such pair is kept.
pub(super) fn in_time(ring: &VecDeque<Sample>, t_ns: u64, half_period_ns: u64) -> Wrench {
    let Some(last) = ring.back() else {
        return Wrench::default();
    };
    let Some(b) = ring
        .iter()
        .rev()
        .find(|q| q.t_ns + half_period_ns <= last.t_ns)
    else {
        return last.w;
    };
    let (p, q) = if b.start_ns == last.start_ns {
        (last, b)
    } else {
        match ring
            .iter()
            .rev()
            .find(|q| q.start_ns == b.start_ns && q.t_ns + half_period_ns <= b.t_ns)
        {
            Some(q) => (b, q),
            None => return last.w,
        }
    };
    let s = ((t_ns - last.t_ns) as f64 / (p.t_ns - q.t_ns) as f64).min(2.0);
    along(&shifted(&q.w, &p.w, &last.w), &last.w, 1.0 + s)
}

/// The wrench `a` would be if `b` were `to`: `a + (to − b)`. A slope from `a` to `b` laid from
/// `to` is `along(&shifted(a, b, to), to, s)`.
fn shifted(a: &Wrench, b: &Wrench, to: &Wrench) -> Wrench {
    let (a, b, to) = (a.to_array(), b.to_array(), to.to_array());
    Wrench::from_array(std::array::from_fn(|k| a[k] + to[k] - b[k]))
}

/// The decision of `ContactPhysics::read_ahead` for an F/T sample at `t_ns` with the
/// indenter at `at` (see [`Sample::at_mm`]), from the buffer `ring`; `start_ns` is the tick a
/// solve at `t_ns` would start from (the nearest one).
pub(super) fn read_off_line(
    ring: &VecDeque<Sample>,
    t_ns: u64,
    at: &[f64; 3],
    start_ns: u64,
) -> Ahead {
    let Some(s1) = ring.back() else {
        return if at[2] > 0.0 {
            Ahead::Solve
        } else {
            Ahead::Wrench(Wrench::default())
        };
    };
    if s1.t_ns >= t_ns {
        return Ahead::Buffer;
    }
    if at[2] <= 0.0 {
        // Out of contact: no force, exactly.
        return Ahead::Wrench(Wrench::default());
    }
    if s1.at_mm[2] <= 0.0 {
        // The first touch since the newest step.
        return Ahead::Solve;
    }
    if s1.start_ns != start_ns {
        // Past half-way to the next tick: the newest solve started from the history before
        // the tick a solve here starts from, and the difference between the two is a jump
        // (where paralines' slide stops, 0.05-0.08 N at the next frame when it was read on).
        return Ahead::Solve;
    }
    let sub = |p: &[f64; 3], q: &[f64; 3]| -> [f64; 3] { std::array::from_fn(|k| p[k] - q[k]) };
    let dot = |p: &[f64; 3], q: &[f64; 3]| -> f64 { (0..3).map(|k| p[k] * q[k]).sum() };
    let v = sub(at, &s1.at_mm);
    let s0 = ring.len().checked_sub(2).map(|i| &ring[i]);
    let d = s0.map(|s0| sub(&s1.at_mm, &s0.at_mm));
    let resting = |x: &[f64; 3]| dot(x, x).sqrt() <= REST_MM;
    if resting(&v) {
        return match d {
            // At rest since the step before: only relaxation moves the wrench.
            Some(d) if resting(&d) => Ahead::Buffer,
            // Between two controller ticks of a motion: the newest step is this pose's.
            _ => Ahead::Wrench(s1.w),
        };
    }
    let (Some(s0), Some(d)) = (s0, d) else {
        return Ahead::Solve;
    };
    if resting(&d) {
        // Starting to move.
        return Ahead::Solve;
    }
    if s0.at_mm[2] <= 0.0 {
        // The line from the last step out of contact bends where the indenter touched: a flat
        // face's force rises at its full stiffness from there, and reading it off the chord
        // from the free gel gave about a tenth of it (0.04 against 0.44 N, a physics period
        // after a cylinder's touch).
        return Ahead::Solve;
    }
    // The line's baseline: the latest earlier step in contact at least MIN_BASE_MM back. Two
    // steps microseconds apart (a frame's and an F/T sample's) give a line whose direction is
    // mostly rounding, and a reach of MAX_LINE_STEPS of their spacing is no reach at all.
    let (s0, d) = ring
        .iter()
        .rev()
        .skip(1)
        .map(|s| (s, sub(&s1.at_mm, &s.at_mm)))
        .find(|(_, d)| dot(d, d).sqrt() >= MIN_BASE_MM)
        .filter(|(s, _)| s.at_mm[2] > 0.0)
        .unwrap_or((s0, d));
    // A displacement along the line, in units of `d`, and how far it lies off the line (mm).
    let onto = |x: &[f64; 3]| {
        let k = dot(x, &d) / dot(&d, &d);
        let off: [f64; 3] = std::array::from_fn(|i| x[i] - k * d[i]);
        (k, dot(&off, &off).sqrt())
    };
    let (s, off) = onto(&v);
    if !(0.0..=MAX_LINE_STEPS).contains(&s)
        || off > OFF_LINE_MM
        || s * dot(&d, &d).sqrt() > MAX_LINE_MM
    {
        return Ahead::Solve;
    }
    if s0.start_ns == s1.start_ns {
        return Ahead::Wrench(along(&s0.w, &s1.w, 1.0 + s));
    }
    // The baseline began from another start: the slope of the line comes from it and an
    // earlier solve of its own start on the same line, and is laid from the newest step.
    let Some((q, k)) = ring
        .iter()
        .rev()
        .filter(|q| q.t_ns < s0.t_ns && q.start_ns == s0.start_ns)
        .map(|q| (q, sub(&s0.at_mm, &q.at_mm)))
        .find(|(_, e)| dot(e, e).sqrt() >= MIN_BASE_MM)
        .map(|(q, e)| (q, onto(&e)))
        .filter(|(q, (k, off))| q.at_mm[2] > 0.0 && *k > 0.0 && *off <= OFF_LINE_MM)
        .map(|(q, (k, _))| (q, k))
    else {
        return Ahead::Solve;
    };
    // `k`: the pair's own spacing along the line, in units of `d`.
    Ahead::Wrench(along(&shifted(&q.w, &s0.w, &s1.w), &s1.w, 1.0 + s / k))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(t_ms: u64, fz: f64, at_mm: [f64; 3]) -> Sample {
        Sample {
            t_ns: t_ms * 1_000_000,
            w: Wrench {
                force_n: [0.1 * fz, 0.0, fz],
                torque_nmm: [0.0; 3],
            },
            at_mm,
            start_ns: tick(t_ms * 1_000_000),
        }
    }

    /// The 20 ms grid's tick nearest `t_ns` (the later one half-way).
    fn tick(t_ns: u64) -> u64 {
        (t_ns + 10_000_000) / 20_000_000 * 20_000_000
    }

    /// A buffer whose solves all started from the newest one's tick (consistent solves).
    fn one_start(v: Vec<Sample>) -> VecDeque<Sample> {
        let start = v.last().map_or(0, |s| s.start_ns);
        v.into_iter()
            .map(|s| Sample {
                start_ns: start,
                ..s
            })
            .collect()
    }

    /// [`read_off_line`] for a sample whose solve would start from its nearest tick.
    fn read(ring: &VecDeque<Sample>, t_ns: u64, at: &[f64; 3]) -> Ahead {
        read_off_line(ring, t_ns, at, tick(t_ns))
    }

    fn fz(a: Ahead) -> Option<f64> {
        match a {
            Ahead::Wrench(w) => Some(w.force_n[2]),
            _ => None,
        }
    }

    /// Pressing down at 40 µm per 20 ms step: −1.0 N then −1.2 N.
    fn pressing() -> VecDeque<Sample> {
        one_start(vec![
            sample(0, -1.0, [1.0, 2.0, 0.40]),
            sample(20, -1.2, [1.0, 2.0, 0.44]),
        ])
    }

    #[test]
    fn a_pose_on_the_line_is_read_off_it_at_its_own_distance() {
        let ring = pressing();
        // 4 µm further down (a slower ramp than the steps' 2 mm/s): a tenth of a step on.
        let f = fz(read(&ring, 29_000_000, &[1.0, 2.0, 0.444])).unwrap();
        assert!((f + 1.22).abs() < 1e-12, "{f}");
        // The same pose as the newest step, later (between controller ticks): its wrench.
        let f = fz(read(&ring, 21_000_000, &[1.0, 2.0, 0.44])).unwrap();
        assert_eq!(f, -1.2);
    }

    #[test]
    fn leaving_the_line_reversing_or_running_far_past_it_asks_for_a_solve() {
        let ring = pressing();
        let t = 25_000_000;
        // A shear starting: off the line by 1 µm.
        assert!(matches!(read(&ring, t, &[1.001, 2.0, 0.44]), Ahead::Solve));
        // Going back up the line (a reversal).
        assert!(matches!(read(&ring, t, &[1.0, 2.0, 0.439]), Ahead::Solve));
        // More than two step spacings past the newest step.
        assert!(matches!(read(&ring, t, &[1.0, 2.0, 0.53]), Ahead::Solve));
        // The first touch since the newest step, which was out of contact.
        let air = one_start(vec![
            sample(0, 0.0, [1.0, 2.0, -0.04]),
            sample(20, 0.0, [1.0, 2.0, -0.001]),
        ]);
        assert!(matches!(read(&air, t, &[1.0, 2.0, 0.02]), Ahead::Solve));
        // Just past the touch: the newest step is in contact, the one before it was not, so
        // their line bends where the gel was touched and is not read off.
        let touched = one_start(vec![
            sample(0, 0.0, [1.0, 2.0, -0.019]),
            sample(20, -0.01, [1.0, 2.0, 0.001]),
        ]);
        assert!(matches!(
            read(&touched, 21_000_000, &[1.0, 2.0, 0.002]),
            Ahead::Solve
        ));
        // Starting to move after a rest.
        let rest = one_start(vec![
            sample(0, -1.0, [1.0, 2.0, 0.44]),
            sample(20, -0.98, [1.0, 2.0, 0.44]),
        ]);
        assert!(matches!(read(&rest, t, &[1.0, 2.0, 0.4399]), Ahead::Solve));
        // Still resting: relaxation, from the buffer in time.
        assert!(matches!(read(&rest, t, &[1.0, 2.0, 0.44]), Ahead::Buffer));
    }

    #[test]
    fn a_reading_reaches_at_most_max_line_mm_past_the_newest_step() {
        // Lifting at 5 mm/s, steps 100 µm apart: 4 µm on is read off the line, 6 µm is not,
        // though both are well within two step spacings.
        let ring = one_start(vec![
            sample(0, -5.0, [0.0, 0.0, 0.60]),
            sample(20, -3.4, [0.0, 0.0, 0.50]),
        ]);
        let f = fz(read(&ring, 21_000_000, &[0.0, 0.0, 0.496])).unwrap();
        assert!((f + 3.336).abs() < 1e-12, "{f}");
        assert!(matches!(
            read(&ring, 21_000_000, &[0.0, 0.0, 0.494]),
            Ahead::Solve
        ));
    }

    #[test]
    fn the_line_runs_through_a_step_far_enough_back() {
        // A frame's step 0.2 µm after an F/T sample's: their own line is all rounding, so the
        // line runs from the step 40 µm back, and a pose 4 µm on is read off it.
        let ring = one_start(vec![
            sample(0, -1.0, [1.0, 2.0, 0.4000]),
            sample(19, -1.2, [1.0, 2.0, 0.4400]),
            sample(20, -1.201, [1.0, 2.0, 0.4402]),
        ]);
        let f = fz(read(&ring, 21_000_000, &[1.0, 2.0, 0.4442])).unwrap();
        // Along the 40.2 µm line from −1.0 N to −1.201 N, 4 µm past its end.
        let want = -1.201 - 0.201 * 4.0 / 40.2;
        assert!((f - want).abs() < 1e-9, "{f} against {want}");
    }

    #[test]
    fn out_of_contact_is_zero_and_a_covered_time_is_the_buffers() {
        let ring = pressing();
        assert_eq!(fz(read(&ring, 25_000_000, &[1.0, 2.0, -0.01])), Some(0.0));
        assert!(matches!(
            read(&ring, 20_000_000, &[1.0, 2.0, 0.44]),
            Ahead::Buffer
        ));
    }

    #[test]
    fn an_unloading_read_off_the_line_stops_at_zero() {
        // Lifting: −0.2 N then −0.05 N 4 µm higher; 3.5 µm higher still is past lift-off.
        let ring = one_start(vec![
            sample(0, -0.2, [0.0, 0.0, 0.1000]),
            sample(20, -0.05, [0.0, 0.0, 0.0960]),
        ]);
        assert_eq!(fz(read(&ring, 21_000_000, &[0.0, 0.0, 0.0925])), Some(0.0));
    }

    #[test]
    fn past_half_way_to_the_next_tick_a_reading_is_anchored_on_a_solve_from_that_tick() {
        // The newest solve (a probe at 22 ms) started from the 20 ms tick's history; a sample
        // at 29 ms starts from it too and is read off the line, one at 31 ms starts from the
        // 40 ms tick's and asks for its own solve, though the pose is on the line.
        let ring = one_start(vec![
            sample(12, -1.0, [1.0, 2.0, 0.40]),
            sample(20, -1.1, [1.0, 2.0, 0.42]),
            sample(22, -1.11, [1.0, 2.0, 0.422]),
        ]);
        assert!(fz(read(&ring, 29_000_000, &[1.0, 2.0, 0.424])).is_some());
        assert!(matches!(
            read(&ring, 31_000_000, &[1.0, 2.0, 0.424]),
            Ahead::Solve
        ));
    }

    #[test]
    fn a_baseline_from_another_start_lends_its_slope_but_not_its_jump() {
        // q and s0 started from the 20 ms tick's history: −5 N/mm along the press. s1, 10 µm
        // on, started from the 40 ms tick's and sits 0.15 N off their line (the jump between
        // starts). 2 µm past s1 is s1's force plus the slope: −1.31 N, where the line through
        // s0 and s1 would give −1.34 N.
        let mut ring = VecDeque::from(vec![
            sample(12, -1.0, [1.0, 2.0, 0.40]),
            sample(20, -1.1, [1.0, 2.0, 0.42]),
            sample(31, -1.3, [1.0, 2.0, 0.43]),
        ]);
        ring[0].start_ns = 20_000_000;
        assert_eq!(ring[2].start_ns, 40_000_000);
        let f = fz(read(&ring, 32_000_000, &[1.0, 2.0, 0.432])).unwrap();
        assert!((f + 1.31).abs() < 1e-9, "{f}");
        // Without an earlier solve of the baseline's start, no slope is known: solve.
        ring.pop_front();
        assert!(matches!(
            read(&ring, 32_000_000, &[1.0, 2.0, 0.432]),
            Ahead::Solve
        ));
    }

    #[test]
    fn relaxing_at_rest_is_extrapolated_from_solves_of_one_start() {
        // At rest: the 0 and 20 ms ticks' steps and a probe at 10 ms (started from the 20 ms
        // tick's history) relax by +1 mN/ms; a probe at 31 ms, started from the 40 ms tick's,
        // is 0.08 N off (the contact re-settling). 4 ms after it: its force plus 4 mN.
        let at = [1.0, 2.0, 0.44];
        let mut ring = VecDeque::from(vec![
            sample(0, -1.00, at),
            sample(10, -0.99, at),
            sample(20, -0.98, at),
            sample(31, -1.05, at),
        ]);
        assert_eq!(
            ring.iter()
                .map(|s| s.start_ns / 1_000_000)
                .collect::<Vec<_>>(),
            [0, 20, 20, 40]
        );
        let f = in_time(&ring, 35_000_000, 10_000_000).force_n[2];
        assert!((f + 1.046).abs() < 1e-9, "{f}");
        // One start throughout: the newest step and the one half a period before it.
        ring.pop_back();
        let f = in_time(&ring, 25_000_000, 10_000_000).force_n[2];
        assert!((f + 0.975).abs() < 1e-9, "{f}");
    }
}
