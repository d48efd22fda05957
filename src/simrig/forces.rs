//! The forces a plan will produce on the simulated sensor, without the robot: every planned
//! trajectory's motion (down, shear, reverse, up, each a trapezoidal-speed linear move at its
//! stage's speed and acceleration) stepped through the sensor physics a run uses
//! ([`Effects::sensor`], at the run's physics rate), for `rig sim forces` and the calibration of
//! the simulated gel against the paper's work range.
//!
//! The wrench is the one the run's F/T twin reads (force on the gel, surface frame); the gel is
//! unloaded between trajectories, as in a run, so every trajectory starts with no history.

use std::sync::Arc;

use rayon::prelude::*;
use rig_core::config::RigConfig;
use rig_core::indenter::Indenter;

use super::sim::{Effects, IndenterPose, Scene, SimError, Simulator};

/// Peak forces of one indenter over the trajectories simulated.
#[derive(Debug, Clone, PartialEq)]
pub struct PlanForces {
    pub indenter: String,
    pub trajectories: usize,
    /// Largest |Fx|, |Fy|, |Fz| over every step, N.
    pub max_abs_n: [f64; 3],
    /// Largest tangential force √(Fx² + Fy²), N.
    pub max_shear_n: f64,
    /// Largest force magnitude |F| (what the run's force limit checks), N.
    pub max_norm_n: f64,
    /// Trajectories in which the contact reached gross slip: |F_t| ≥ 0.98 μ |F_n| at some step
    /// with |F_n| above 0.05 N.
    pub gross_slip: usize,
    /// Steps solved.
    pub steps: u64,
}

/// One trajectory's peaks: |Fx|, |Fy|, |Fz|; shear; |F|; gross slip reached; steps.
type Peaks = ([f64; 3], f64, f64, bool, u64);

/// Position along a linear move of length `len` at time `t` since its start, for a
/// trapezoidal speed profile (cruise speed `v`, acceleration `a`; a triangle when too short to
/// cruise), and the move's duration.
pub fn trapezoid(len: f64, v: f64, a: f64, t: f64) -> (f64, f64) {
    if len <= 0.0 {
        return (0.0, 0.0);
    }
    let t_acc = v / a;
    let d_acc = 0.5 * a * t_acc * t_acc;
    if 2.0 * d_acc >= len {
        // Triangle: accelerate to the middle, then brake.
        let t_half = (len / a).sqrt();
        let total = 2.0 * t_half;
        let t = t.clamp(0.0, total);
        let s = if t <= t_half {
            0.5 * a * t * t
        } else {
            len - 0.5 * a * (total - t).powi(2)
        };
        return (s, total);
    }
    let t_cruise = (len - 2.0 * d_acc) / v;
    let total = 2.0 * t_acc + t_cruise;
    let t = t.clamp(0.0, total);
    let s = if t <= t_acc {
        0.5 * a * t * t
    } else if t <= t_acc + t_cruise {
        d_acc + v * (t - t_acc)
    } else {
        len - 0.5 * a * (total - t).powi(2)
    };
    (s, total)
}

/// The poses of one trajectory (in contact only: from the surface down, shear, reverse, up to
/// the surface), sampled every `1 / rate_hz` s, with their times.
pub fn trajectory_poses(
    config: &RigConfig,
    point: [f64; 2],
    depth_mm: f64,
    direction_deg: f64,
    rate_hz: f64,
) -> Vec<(f64, IndenterPose)> {
    let plan = &config.plan;
    let (sin, cos) = direction_deg.to_radians().sin_cos();
    let dist = plan.shear_distance_mm;
    // (stage length, speed, acceleration, pose at stage progress s).
    type PoseAt<'a> = Box<dyn Fn(f64) -> (f64, f64) + 'a>;
    let stages: [(f64, f64, f64, PoseAt); 4] = [
        (
            depth_mm,
            plan.down.speed_mm_s,
            plan.down.accel_mm_s2,
            Box::new(|s| (s, 0.0)),
        ),
        (
            dist,
            plan.shear.speed_mm_s,
            plan.shear.accel_mm_s2,
            Box::new(|s| (depth_mm, s)),
        ),
        (
            dist,
            plan.shear.speed_mm_s,
            plan.shear.accel_mm_s2,
            Box::new(move |s| (depth_mm, dist - s)),
        ),
        (
            depth_mm,
            plan.up.speed_mm_s,
            plan.up.accel_mm_s2,
            Box::new(move |s| (depth_mm - s, 0.0)),
        ),
    ];
    let dt = 1.0 / rate_hz;
    let mut out = Vec::new();
    let mut t0 = 0.0;
    for (len, v, a, pose_at) in &stages {
        let (_, total) = trapezoid(*len, *v, *a, 0.0);
        let n = (total / dt).ceil().max(1.0) as usize;
        for k in 1..=n {
            let t = (k as f64 * dt).min(total);
            let (s, _) = trapezoid(*len, *v, *a, t);
            let (d, sh) = pose_at(s);
            out.push((
                t0 + t,
                IndenterPose {
                    contact_mm: point,
                    depth_mm: d,
                    shear_mm: [sh * cos, sh * sin],
                },
            ));
        }
        t0 += total;
    }
    out
}

/// Simulates the plan's trajectories for `indenter` (every depth, or the deepest only when
/// `deepest_only`: the forces peak there) and returns the peaks. Trajectories run in parallel
/// on rayon's pool; `tick` is called once per finished trajectory (for a progress bar).
pub fn plan_forces(
    config: &RigConfig,
    indenter: &Indenter,
    deepest_only: bool,
    rate_hz: f64,
    tick: &(dyn Fn() + Sync),
) -> Result<PlanForces, SimError> {
    let plan = &config.plan;
    let deepest = plan.depths_mm.iter().copied().fold(0.0, f64::max);
    let depths: Vec<f64> = if deepest_only {
        vec![deepest]
    } else {
        plan.depths_mm.clone()
    };
    let mut jobs = Vec::new();
    for &p in &plan.contact_points_mm {
        for &d in &depths {
            for &dir in &plan.directions_deg {
                jobs.push((p, d, dir));
            }
        }
    }
    let indenter = Arc::new(indenter.clone());
    let effects = Effects::sensor(&config.elastomer);
    let mu = config.elastomer.friction_coefficient;
    let results: Vec<Result<Peaks, SimError>> = jobs
        .par_iter()
        .map_init(Simulator::new, |sim, &(p, d, dir)| {
            sim.reset();
            let mut scene = Scene::new(
                config.elastomer.clone(),
                indenter.clone(),
                IndenterPose {
                    contact_mm: p,
                    depth_mm: 0.0,
                    shear_mm: [0.0, 0.0],
                },
            );
            scene.effects = effects.clone();
            let (mut max_abs, mut shear, mut norm, mut slip) = ([0.0; 3], 0.0_f64, 0.0_f64, false);
            let poses = trajectory_poses(config, p, d, dir, rate_hz);
            for (t, pose) in &poses {
                scene.pose = *pose;
                let f = sim.step(&scene, *t)?.wrench.force_n;
                for (m, x) in max_abs.iter_mut().zip(f) {
                    *m = f64::max(*m, x.abs());
                }
                let ft = f[0].hypot(f[1]);
                shear = shear.max(ft);
                norm = norm.max(ft.hypot(f[2]));
                slip |= f[2].abs() > 0.05 && ft >= 0.98 * mu * f[2].abs();
            }
            tick();
            Ok((max_abs, shear, norm, slip, poses.len() as u64))
        })
        .collect();
    let mut out = PlanForces {
        indenter: indenter.name().to_owned(),
        trajectories: jobs.len(),
        max_abs_n: [0.0; 3],
        max_shear_n: 0.0,
        max_norm_n: 0.0,
        gross_slip: 0,
        steps: 0,
    };
    for r in results {
        let (m, shear, norm, slip, steps) = r?;
        for (o, x) in out.max_abs_n.iter_mut().zip(m) {
            *o = o.max(x);
        }
        out.max_shear_n = out.max_shear_n.max(shear);
        out.max_norm_n = out.max_norm_n.max(norm);
        out.gross_slip += usize::from(slip);
        out.steps += steps;
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_trapezoid_reaches_its_length_at_its_duration_and_cruises_at_its_speed() {
        let (s, total) = trapezoid(1.0, 1.0, 10.0, 0.0);
        assert_eq!(s, 0.0);
        assert!((total - 1.1).abs() < 1e-12, "{total}");
        assert!((trapezoid(1.0, 1.0, 10.0, total).0 - 1.0).abs() < 1e-12);
        let (a, _) = trapezoid(1.0, 1.0, 10.0, 0.5);
        let (b, _) = trapezoid(1.0, 1.0, 10.0, 0.6);
        assert!(((b - a) / 0.1 - 1.0).abs() < 1e-9);
        // Too short to cruise: a triangle, symmetric about its middle.
        let (_, total) = trapezoid(0.02, 1.0, 10.0, 0.0);
        assert!((total - 2.0 * (0.02f64 / 10.0).sqrt()).abs() < 1e-12);
        assert!((trapezoid(0.02, 1.0, 10.0, total / 2.0).0 - 0.01).abs() < 1e-12);
    }

    #[test]
    fn a_trajectory_goes_down_shears_out_and_back_and_comes_up() {
        let config = rig_core::config::RigConfig::sim_source();
        let poses = trajectory_poses(&config, [1.0, -2.0], 0.8, 90.0, 50.0);
        let deepest = poses.iter().map(|(_, p)| p.depth_mm).fold(0.0, f64::max);
        assert!((deepest - 0.8).abs() < 1e-12);
        let widest = poses.iter().map(|(_, p)| p.shear_mm[1]).fold(0.0, f64::max);
        assert!((widest - config.plan.shear_distance_mm).abs() < 1e-9);
        assert!(poses.iter().all(|(_, p)| p.shear_mm[0].abs() < 1e-12));
        let (_, last) = poses.last().expect("poses");
        assert!(last.depth_mm.abs() < 1e-12 && last.shear_mm[1].abs() < 1e-12);
        assert!(poses.windows(2).all(|w| w[1].0 > w[0].0));
    }
}
