//! Straight-line motion of the simulated TCP: the trapezoidal velocity profile of `movel`, and
//! the decelerations of `stopl` and of a protective stop.
//!
//! Everything here is pure: a [`LinearMove`] is evaluated at an absolute clock time, computed
//! analytically from the move's start time, so a long move accumulates no integration drift
//! and a test can compute the expected pose at any tick by hand.
//!
//! Path units: a move with a translation of at least [`MIN_TRANSLATION_M`] is parametrised by
//! the distance travelled along the line (metres; speed in m/s, acceleration in m/s²), and the
//! orientation follows the same path parameter through [`rig_core::pose::interpolate`]. A pure
//! rotation is parametrised by the rotation angle (radians; speed in rad/s, acceleration in
//! rad/s²), as URScript `movel` does when only the orientation changes.
//!
//! The controller's joint-space tracking error is not modelled: the reported actual pose is the
//! profile's pose exactly.

use nalgebra::Vector3;
use rig_core::pose::{self, Pose};

/// Below this translation (m) a move is treated as a pure rotation.
pub const MIN_TRANSLATION_M: f64 = 1e-6;

/// A velocity profile along a path of length `length`: `s(t)` and `ṡ(t)` for `t ≥ 0` seconds
/// since the profile's start.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Profile {
    /// Accelerate with `accel` to `v_peak`, cruise, decelerate with `accel` to rest at `length`.
    /// When the path is too short to reach the commanded speed, `v_peak = √(length · accel)` and
    /// there is no cruise phase (a triangle).
    Trapezoid {
        length: f64,
        v_peak: f64,
        accel: f64,
        t_accel: f64,
        t_total: f64,
    },
    /// Decelerate from `s0`, `v0` with `decel` to rest (stopl, protective stop).
    Decel { s0: f64, v0: f64, decel: f64 },
}

impl Profile {
    /// The trapezoid for a path of `length` with commanded speed `v` and acceleration `a`
    /// (both finite and positive; checked by the caller).
    pub fn trapezoid(length: f64, v: f64, a: f64) -> Self {
        let length = length.max(0.0);
        // The speed is reached when the acceleration and deceleration distances, v²/(2a) each,
        // fit into the path; otherwise the profile is a triangle peaking at √(L·a).
        let v_peak = if length * a >= v * v {
            v
        } else {
            (length * a).sqrt()
        };
        let t_accel = v_peak / a;
        let d_accel = 0.5 * v_peak * t_accel;
        let t_cruise = if v_peak > 0.0 {
            (length - 2.0 * d_accel).max(0.0) / v_peak
        } else {
            0.0
        };
        Self::Trapezoid {
            length,
            v_peak,
            accel: a,
            t_accel,
            t_total: 2.0 * t_accel + t_cruise,
        }
    }

    /// Duration until rest, seconds.
    pub fn duration(&self) -> f64 {
        match *self {
            Self::Trapezoid { t_total, .. } => t_total,
            Self::Decel { v0, decel, .. } => v0 / decel,
        }
    }

    /// Path position and speed at `t` seconds since the profile's start (clamped to the end).
    pub fn eval(&self, t: f64) -> (f64, f64) {
        let t = t.max(0.0);
        match *self {
            Self::Trapezoid {
                length,
                v_peak,
                accel,
                t_accel,
                t_total,
            } => {
                if t >= t_total {
                    (length, 0.0)
                } else if t < t_accel {
                    (0.5 * accel * t * t, accel * t)
                } else if t <= t_total - t_accel {
                    (0.5 * v_peak * t_accel + v_peak * (t - t_accel), v_peak)
                } else {
                    let r = t_total - t;
                    (length - 0.5 * accel * r * r, accel * r)
                }
            }
            Self::Decel { s0, v0, decel } => {
                let t_stop = v0 / decel;
                let t = t.min(t_stop);
                (s0 + v0 * t - 0.5 * decel * t * t, v0 - decel * t)
            }
        }
    }
}

/// Which quantity parametrises the path.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PathKind {
    /// Metres along the straight line; the rotation follows by the same fraction.
    Translation,
    /// Radians of the rotation (translation below [`MIN_TRANSLATION_M`]).
    Rotation,
}

/// One `movel` in progress (possibly being stopped).
#[derive(Debug, Clone, PartialEq)]
pub struct LinearMove {
    pub start: Pose,
    pub target: Pose,
    pub kind: PathKind,
    /// Path length in path units (m or rad).
    pub length: f64,
    /// The commanded acceleration (path units/s²).
    pub accel: f64,
    /// Clock time at which `profile` starts, ns.
    pub profile_start_ns: u64,
    pub profile: Profile,
    /// Unit direction of travel in the base frame (translation moves).
    direction: Vector3<f64>,
    /// Rotation from start to target as a base-frame rotation vector (axis × angle).
    rotation_base: Vector3<f64>,
}

/// Pose, TCP speed `[vx, vy, vz, wx, wy, wz]` (base frame) and whether the motion has ended.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MotionState {
    pub pose: Pose,
    pub speed: [f64; 6],
    pub finished: bool,
}

impl LinearMove {
    /// A move from `start` to `target` at speed `v` and acceleration `a`, starting at `t0_ns`.
    pub fn new(start: Pose, target: Pose, v: f64, a: f64, t0_ns: u64) -> Self {
        let delta = target.position() - start.position();
        let translation = delta.norm();
        let ra = start.rotation();
        let rel = ra.transpose() * target.rotation();
        // Base-frame rotation vector of the move: R_a · log(R_aᵀ R_b), matching interpolate's
        // R(s) = R_a · exp(s · log(R_aᵀ R_b)).
        let rotation_base = ra * rel.scaled_axis();
        let (kind, length, direction) = if translation >= MIN_TRANSLATION_M {
            (PathKind::Translation, translation, delta / translation)
        } else {
            (PathKind::Rotation, rotation_base.norm(), Vector3::zeros())
        };
        Self {
            start,
            target,
            kind,
            length,
            accel: a,
            profile_start_ns: t0_ns,
            profile: Profile::trapezoid(length, v, a),
            direction,
            rotation_base,
        }
    }

    fn t_since_start(&self, t_ns: u64) -> f64 {
        t_ns.saturating_sub(self.profile_start_ns) as f64 * 1e-9
    }

    /// The motion at clock time `t_ns`.
    pub fn state_at(&self, t_ns: u64) -> MotionState {
        let t = self.t_since_start(t_ns);
        let (s, sdot) = self.profile.eval(t);
        let finished = t >= self.profile.duration();
        let (u, udot) = if self.length > 0.0 {
            ((s / self.length).clamp(0.0, 1.0), sdot / self.length)
        } else {
            (1.0, 0.0)
        };
        let pose = if finished && matches!(self.profile, Profile::Trapezoid { .. }) {
            self.target
        } else {
            pose::interpolate(&self.start, &self.target, u)
        };
        let lin = match self.kind {
            PathKind::Translation => self.direction * sdot,
            PathKind::Rotation => Vector3::zeros(),
        };
        let ang = self.rotation_base * udot;
        let speed = if finished {
            [0.0; 6]
        } else {
            [lin.x, lin.y, lin.z, ang.x, ang.y, ang.z]
        };
        MotionState {
            pose,
            speed,
            finished,
        }
    }

    /// Replace the rest of the profile with a deceleration at `decel` (path units/s²) from
    /// the state at `t_ns`. The deceleration is raised if needed so the TCP comes to rest on
    /// the path, never past the target.
    pub fn begin_stop(&mut self, t_ns: u64, decel: f64) {
        let (s0, v0) = self.profile.eval(self.t_since_start(t_ns));
        let remaining = (self.length - s0).max(0.0);
        let mut decel = decel;
        if v0 > 0.0 && remaining > 0.0 {
            decel = decel.max(v0 * v0 / (2.0 * remaining));
        }
        if v0 <= 0.0 || remaining <= 0.0 || !decel.is_finite() {
            // Already at rest (or at the end): stop right here.
            self.profile = Profile::Decel {
                s0,
                v0: 0.0,
                decel: 1.0,
            };
        } else {
            self.profile = Profile::Decel { s0, v0, decel };
        }
        self.profile_start_ns = t_ns;
    }

    /// Whether the move is being stopped rather than completing.
    pub fn is_stopping(&self) -> bool {
        matches!(self.profile, Profile::Decel { .. })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trapezoid_reaches_the_commanded_speed_when_the_path_is_long_enough() {
        // L = 0.1 m, v = 0.25 m/s, a = 1.2 m/s²: accel distance 0.026 m each way, fits.
        let p = Profile::trapezoid(0.1, 0.25, 1.2);
        let expected = 0.1 / 0.25 + 0.25 / 1.2;
        assert!((p.duration() - expected).abs() < 1e-12);
        let (s, v) = p.eval(0.3);
        assert!((v - 0.25).abs() < 1e-12);
        assert!(s > 0.0 && s < 0.1);
        assert_eq!(p.eval(1.0), (0.1, 0.0));
        // Continuous at the phase boundaries.
        let t_a = 0.25 / 1.2;
        let (s1, _) = p.eval(t_a - 1e-9);
        let (s2, _) = p.eval(t_a + 1e-9);
        assert!((s1 - s2).abs() < 1e-9);
    }

    #[test]
    fn short_path_gives_a_triangle() {
        // L = 0.01 m, a = 1 m/s²: v_peak = 0.1 m/s < 0.5 commanded; T = 2·√(L/a) = 0.2 s.
        let p = Profile::trapezoid(0.01, 0.5, 1.0);
        assert!((p.duration() - 0.2).abs() < 1e-12);
        let (s, v) = p.eval(0.1);
        assert!((v - 0.1).abs() < 1e-12);
        assert!((s - 0.005).abs() < 1e-12);
    }

    #[test]
    fn pure_rotation_uses_the_angle_and_rad_per_s() {
        let start = Pose::new(0.1, 0.2, 0.3, 0.0, 0.0, 0.0);
        let target = Pose::new(0.1, 0.2, 0.3, 0.0, 0.0, 0.5);
        // L = 0.5 rad, v = 1 rad/s, a = 2 rad/s²: v²/a = L, so T = L/v + v/a = 1 s, no cruise.
        let m = LinearMove::new(start, target, 1.0, 2.0, 0);
        assert_eq!(m.kind, PathKind::Rotation);
        assert!((m.profile.duration() - 1.0).abs() < 1e-12);
        let mid = m.state_at(500_000_000);
        assert!((mid.speed[5] - 1.0).abs() < 1e-12, "{:?}", mid.speed);
        assert_eq!(&mid.speed[..3], &[0.0; 3]);
        assert!((mid.pose.rz - 0.25).abs() < 1e-12);
        assert!((mid.pose.x - 0.1).abs() < 1e-15);
        let end = m.state_at(1_000_000_000);
        assert!(end.finished);
        assert_eq!(end.pose, target);
    }

    #[test]
    fn stop_decelerates_along_the_path() {
        let start = Pose::new(0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        let target = Pose::new(1.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        let mut m = LinearMove::new(start, target, 0.5, 1.0, 0);
        let t = 1_000_000_000; // cruising at 0.5 m/s, s = 0.375 m
        m.begin_stop(t, 2.0);
        let end = m.state_at(t + 2_000_000_000);
        assert!(end.finished);
        // s = 0.375 + 0.5²/(2·2) = 0.4375
        assert!((end.pose.x - 0.4375).abs() < 1e-12, "{}", end.pose.x);
        assert_eq!(end.speed, [0.0; 6]);
    }
}
