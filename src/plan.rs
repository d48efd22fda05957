//! The contact plan: every trajectory the rig will run, as TCP poses in the robot base frame,
//! checked against the safety limits before anything moves.
//!
//! The paper's collection protocol (TransForce, "Collection"): at each of 5 contact points, for
//! each of 4 depths (0.2 mm steps to 0.8 mm) and each of 12 directions (30° apart), the indenter
//! goes **down** to the depth, **shears** horizontally along the direction, moves back
//! (**reverse**) to the start at depth, and goes **up**: 5 × 4 × 12 = 240 trajectories per
//! indenter and sensor. The numbers come from `[plan]` of the rig config; the defaults are the
//! paper's.
//!
//! Order: point → depth → direction (the robot stays at one contact point for 48 trajectories).
//! Ids are `p{point}-d{depth_mm}-a{angle_deg}`, e.g. `p4-d0.8-a090`: stable across runs and safe
//! in file names (see [`rig_core::config::format_depth_mm`] and
//! [`rig_core::config::format_angle_deg`]).
//!
//! Geometry: a waypoint is built in the sensor surface frame (position `(x, y, z)` in mm with
//! z = +approach height above the surface or −depth below it, orientation "tool down", rotation
//! vector `(π, 0, 0)`) and mapped to the base frame with `pose_trans(surface_frame, local)`.
//! Each stage lists its waypoints from its start (= the previous stage's end) to its end; the
//! robot moves in straight lines (`moveL`) between consecutive waypoints, stopping at each.
//!
//! Safety: [`Plan::build`] validates the config, then checks **every** waypoint against the
//! envelope box, `safety.max_depth_mm` and the elastomer thickness (depth recomputed from the
//! base-frame pose, so an error in the pose maths or the surface frame is caught too). Because
//! the envelope is a box (convex) and moves are straight lines, the segments between checked
//! waypoints stay inside as well, including the moves between trajectories, which join the end
//! of one trajectory to the start of the next at approach height.

use std::f64::consts::PI;
use std::fmt;

use rig_core::config::{
    ConfigError, Envelope, RigConfig, StageMotion, format_angle_deg, format_depth_mm,
};
use rig_core::indenter::Indenter;
use rig_core::pose::{Pose, pose_inv, pose_trans};
use serde::{Serialize, Serializer};

/// Depth comparisons tolerate this much rounding from the pose maths (mm): a nanometre.
const DEPTH_TOLERANCE_MM: f64 = 1e-6;

/// The four stages of a trajectory, in order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum StageName {
    /// From approach height above the contact point straight down to the depth.
    Down,
    /// At depth, along the direction by `plan.shear_distance_mm`.
    Shear,
    /// At depth, back to the contact point.
    Reverse,
    /// From the depth straight up to approach height.
    Up,
}

impl StageName {
    /// All stages in execution order.
    pub const ALL: [StageName; 4] = [
        StageName::Down,
        StageName::Shear,
        StageName::Reverse,
        StageName::Up,
    ];

    /// Lower-case name, as in JSON and recordings.
    pub fn as_str(self) -> &'static str {
        match self {
            StageName::Down => "down",
            StageName::Shear => "shear",
            StageName::Reverse => "reverse",
            StageName::Up => "up",
        }
    }
}

impl fmt::Display for StageName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// One stage: straight moves through `waypoints` at the stage's speed and acceleration.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Stage {
    pub name: StageName,
    /// TCP cruise speed, mm/s.
    pub speed_mm_s: f64,
    /// TCP acceleration, mm/s².
    pub accel_mm_s2: f64,
    /// TCP poses in the robot base frame; `waypoints[0]` is where the stage starts.
    #[serde(serialize_with = "poses_as_arrays")]
    pub waypoints: Vec<Pose>,
}

impl Stage {
    /// Path length through the waypoints, mm.
    pub fn length_mm(&self) -> f64 {
        self.waypoints
            .windows(2)
            .map(|w| (w[1].position() - w[0].position()).norm() * 1000.0)
            .sum()
    }

    /// Time to run the stage with a trapezoidal speed profile that stops at every waypoint, s.
    pub fn duration_estimate_s(&self) -> f64 {
        self.waypoints
            .windows(2)
            .map(|w| {
                let len = (w[1].position() - w[0].position()).norm() * 1000.0;
                trapezoid_time_s(len, self.speed_mm_s, self.accel_mm_s2)
            })
            .sum()
    }
}

/// Time of a rest-to-rest move of `len_mm` with cruise speed `v` and acceleration `a`.
pub fn trapezoid_time_s(len_mm: f64, v_mm_s: f64, a_mm_s2: f64) -> f64 {
    if len_mm <= 0.0 {
        return 0.0;
    }
    if len_mm >= v_mm_s * v_mm_s / a_mm_s2 {
        // Accelerate to v, cruise, decelerate: the ramps together cover v²/a in 2v/a.
        len_mm / v_mm_s + v_mm_s / a_mm_s2
    } else {
        // Triangular profile: never reaches v.
        2.0 * (len_mm / a_mm_s2).sqrt()
    }
}

/// One press: down, shear, reverse, up at one point, depth and direction.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Trajectory {
    /// Stable, filename-safe id, e.g. `p4-d0.8-a090`.
    pub id: String,
    /// Index into `plan.contact_points_mm`.
    pub point: usize,
    /// Contact point `[x, y]` in the surface frame, mm.
    pub point_mm: [f64; 2],
    /// Depth below the undeformed surface, mm.
    pub depth_mm: f64,
    /// Shear direction in the surface frame, degrees from +x towards +y.
    pub angle_deg: f64,
    /// `down`, `shear`, `reverse`, `up`, in that order.
    pub stages: Vec<Stage>,
}

impl Trajectory {
    /// The stage called `name`.
    pub fn stage(&self, name: StageName) -> Option<&Stage> {
        self.stages.iter().find(|s| s.name == name)
    }

    /// Sum of the stage duration estimates, s.
    pub fn duration_estimate_s(&self) -> f64 {
        self.stages.iter().map(Stage::duration_estimate_s).sum()
    }
}

/// A waypoint outside a limit.
#[derive(Debug, Clone, PartialEq)]
pub struct Violation {
    /// Trajectory id.
    pub trajectory: String,
    pub stage: StageName,
    /// Index into the stage's waypoints.
    pub waypoint: usize,
    /// The limit and by how much it is exceeded, naming the config key.
    pub reason: String,
}

impl fmt::Display for Violation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "trajectory {}, stage {}, waypoint {}: {}",
            self.trajectory, self.stage, self.waypoint, self.reason
        )
    }
}

/// Why no plan could be made. Nothing has moved when this is returned.
#[derive(Debug, thiserror::Error)]
pub enum PlanError {
    /// The rig config is invalid.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// Waypoints outside the safety limits; the first is shown, all are kept.
    #[error("{}", unsafe_message(.0))]
    Unsafe(Vec<Violation>),
    /// Two trajectories would get the same id (and overwrite each other's recordings).
    #[error(
        "two trajectories would both be called {0}; make plan.depths_mm and plan.directions_deg distinct"
    )]
    DuplicateId(String),
}

fn unsafe_message(v: &[Violation]) -> String {
    match v {
        [] => "unsafe plan".to_owned(),
        [one] => format!("unsafe plan: {one}"),
        [first, rest @ ..] => format!(
            "unsafe plan: {first} (and {} more waypoints outside the limits)",
            rest.len()
        ),
    }
}

impl PlanError {
    /// The waypoint violations, when the plan was refused for safety.
    pub fn violations(&self) -> &[Violation] {
        match self {
            PlanError::Unsafe(v) => v,
            _ => &[],
        }
    }
}

/// Closest approach of the plan to each face of the envelope, mm (negative: outside).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct EnvelopeMargins {
    pub min_x_mm: f64,
    pub max_x_mm: f64,
    pub min_y_mm: f64,
    pub max_y_mm: f64,
    pub min_z_mm: f64,
    pub max_z_mm: f64,
}

impl EnvelopeMargins {
    /// `(config key under safety.envelope, margin mm)` for the six faces.
    pub fn faces(&self) -> [(&'static str, f64); 6] {
        [
            ("min_x", self.min_x_mm),
            ("max_x", self.max_x_mm),
            ("min_y", self.min_y_mm),
            ("max_y", self.max_y_mm),
            ("min_z", self.min_z_mm),
            ("max_z", self.max_z_mm),
        ]
    }
}

/// A checked contact plan for one indenter on one rig.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Plan {
    /// Indenter name.
    pub indenter: String,
    /// `sensor.id` of the rig.
    pub sensor_id: String,
    /// The gel surface frame the plan was built for (base frame).
    #[serde(serialize_with = "pose_as_array")]
    pub surface_frame: Pose,
    pub trajectories: Vec<Trajectory>,
}

impl Plan {
    /// Builds every trajectory of the config's plan and checks every waypoint against the safety
    /// limits. Returns the plan only if all of it is safe.
    pub fn build(config: &RigConfig, indenter: &Indenter) -> Result<Plan, PlanError> {
        config.validate().map_err(|problems| ConfigError::Invalid {
            origin: "(in memory)".to_owned(),
            problems,
        })?;
        let p = &config.plan;
        let frame = config.sensor.surface_frame;
        let mut trajectories = Vec::with_capacity(
            p.contact_points_mm.len() * p.depths_mm.len() * p.directions_deg.len(),
        );
        let mut ids = std::collections::HashSet::new();
        for (point, &[cx, cy]) in p.contact_points_mm.iter().enumerate() {
            for &depth_mm in &p.depths_mm {
                for &angle_deg in &p.directions_deg {
                    let id = format!(
                        "p{point}-d{}-a{}",
                        format_depth_mm(depth_mm),
                        format_angle_deg(angle_deg)
                    );
                    if !ids.insert(id.clone()) {
                        return Err(PlanError::DuplicateId(id));
                    }
                    let (sin, cos) = angle_deg.to_radians().sin_cos();
                    let (ex, ey) = (
                        cx + p.shear_distance_mm * cos,
                        cy + p.shear_distance_mm * sin,
                    );
                    let above = local_tool_down(&frame, cx, cy, p.approach_height_mm);
                    let start = local_tool_down(&frame, cx, cy, -depth_mm);
                    let end = local_tool_down(&frame, ex, ey, -depth_mm);
                    let stage = |name, m: &StageMotion, waypoints| Stage {
                        name,
                        speed_mm_s: m.speed_mm_s,
                        accel_mm_s2: m.accel_mm_s2,
                        waypoints,
                    };
                    trajectories.push(Trajectory {
                        id,
                        point,
                        point_mm: [cx, cy],
                        depth_mm,
                        angle_deg,
                        stages: vec![
                            stage(StageName::Down, &p.down, vec![above, start]),
                            stage(StageName::Shear, &p.shear, vec![start, end]),
                            stage(StageName::Reverse, &p.shear, vec![end, start]),
                            stage(StageName::Up, &p.up, vec![start, above]),
                        ],
                    });
                }
            }
        }
        let plan = Plan {
            indenter: indenter.name().to_owned(),
            sensor_id: config.sensor.id.clone(),
            surface_frame: frame,
            trajectories,
        };
        plan.check(config)?;
        Ok(plan)
    }

    /// Checks every waypoint against `safety.envelope`, `safety.max_depth_mm` and
    /// `elastomer.thickness_mm` of `config`; all violations are returned.
    pub fn check(&self, config: &RigConfig) -> Result<(), PlanError> {
        let env = &config.safety.envelope;
        let to_surface = pose_inv(&config.sensor.surface_frame);
        let mut violations = Vec::new();
        for t in &self.trajectories {
            for s in &t.stages {
                for (i, wp) in s.waypoints.iter().enumerate() {
                    let mut flag = |reason: String| {
                        violations.push(Violation {
                            trajectory: t.id.clone(),
                            stage: s.name,
                            waypoint: i,
                            reason,
                        })
                    };
                    for reason in envelope_violations(env, wp) {
                        flag(reason);
                    }
                    let depth_mm = -pose_trans(&to_surface, wp).z * 1000.0;
                    if !depth_mm.is_finite() {
                        flag("pose is not finite".to_owned());
                    } else if depth_mm > config.elastomer.thickness_mm + DEPTH_TOLERANCE_MM {
                        flag(format!(
                            "depth {depth_mm:.4} mm exceeds elastomer.thickness_mm = {:?} mm",
                            config.elastomer.thickness_mm
                        ));
                    } else if depth_mm > config.safety.max_depth_mm + DEPTH_TOLERANCE_MM {
                        flag(format!(
                            "depth {depth_mm:.4} mm exceeds safety.max_depth_mm = {:?} mm",
                            config.safety.max_depth_mm
                        ));
                    }
                }
            }
        }
        if violations.is_empty() {
            Ok(())
        } else {
            Err(PlanError::Unsafe(violations))
        }
    }

    /// Number of waypoints over all stages (each stage counts its start).
    pub fn waypoint_count(&self) -> usize {
        self.trajectories
            .iter()
            .flat_map(|t| &t.stages)
            .map(|s| s.waypoints.len())
            .sum()
    }

    /// Estimated time of every stage, s (moves between contact points not included).
    pub fn duration_estimate_s(&self) -> f64 {
        self.trajectories
            .iter()
            .map(Trajectory::duration_estimate_s)
            .sum()
    }

    /// Total estimated time per stage name, s, in stage order.
    pub fn stage_durations_s(&self) -> [(StageName, f64); 4] {
        StageName::ALL.map(|name| {
            let total = self
                .trajectories
                .iter()
                .filter_map(|t| t.stage(name))
                .map(Stage::duration_estimate_s)
                .sum();
            (name, total)
        })
    }

    /// How close the plan comes to each face of `env`, mm.
    pub fn envelope_margins(&self, env: &Envelope) -> EnvelopeMargins {
        let mut m = [f64::INFINITY; 6];
        for wp in self
            .trajectories
            .iter()
            .flat_map(|t| &t.stages)
            .flat_map(|s| &s.waypoints)
        {
            let p = [wp.x, wp.y, wp.z];
            for (k, (_, limit, is_min, axis)) in env.limits().into_iter().enumerate() {
                let margin = if is_min {
                    p[axis] - limit
                } else {
                    limit - p[axis]
                };
                m[k] = m[k].min(margin * 1000.0);
            }
        }
        EnvelopeMargins {
            min_x_mm: m[0],
            max_x_mm: m[1],
            min_y_mm: m[2],
            max_y_mm: m[3],
            min_z_mm: m[4],
            max_z_mm: m[5],
        }
    }
}

/// Base-frame TCP pose at `(x_mm, y_mm, z_mm)` of the surface frame with the tool pointing down
/// into the gel (rotation vector `(π, 0, 0)` relative to the surface frame).
fn local_tool_down(frame: &Pose, x_mm: f64, y_mm: f64, z_mm: f64) -> Pose {
    let local = Pose::new(x_mm / 1000.0, y_mm / 1000.0, z_mm / 1000.0, PI, 0.0, 0.0);
    pose_trans(frame, &local)
}

/// Reasons a base-frame pose lies outside `env`, naming the limit.
fn envelope_violations(env: &Envelope, wp: &Pose) -> Vec<String> {
    let p = [wp.x, wp.y, wp.z];
    let axis_name = ["x", "y", "z"];
    env.limits()
        .into_iter()
        .filter_map(|(key, limit, is_min, axis)| {
            let v = p[axis];
            // NaN counts as outside: `partial_cmp` is None for it.
            let inside = match v.partial_cmp(&limit) {
                Some(std::cmp::Ordering::Greater) => is_min,
                Some(std::cmp::Ordering::Less) => !is_min,
                Some(std::cmp::Ordering::Equal) => true,
                None => false,
            };
            let outside = !inside;
            outside.then(|| {
                let (vs, ls) = distinct_decimals(v, limit);
                format!(
                    "{} = {vs} m is {} safety.envelope.{key} = {ls} m",
                    axis_name[axis],
                    if is_min { "below" } else { "above" }
                )
            })
        })
        .collect()
}

/// Formats two different numbers with 4 decimals, or more if 4 would show them equal.
fn distinct_decimals(a: f64, b: f64) -> (String, String) {
    for decimals in 4..=12 {
        let (sa, sb) = (format!("{a:.decimals$}"), format!("{b:.decimals$}"));
        if sa != sb {
            return (sa, sb);
        }
    }
    (format!("{a:?}"), format!("{b:?}"))
}

fn poses_as_arrays<S: Serializer>(poses: &[Pose], s: S) -> Result<S::Ok, S::Error> {
    s.collect_seq(poses.iter().map(Pose::to_array))
}

fn pose_as_array<S: Serializer>(pose: &Pose, s: S) -> Result<S::Ok, S::Error> {
    pose.to_array().serialize(s)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rig_core::pose::rotation_distance;

    fn sim_plan() -> Plan {
        Plan::build(
            &RigConfig::sim_source(),
            &Indenter::builtin("cone").unwrap(),
        )
        .unwrap()
    }

    #[test]
    fn default_plan_has_240_trajectories_in_order() {
        let plan = sim_plan();
        assert_eq!(plan.trajectories.len(), 240);
        assert_eq!(plan.trajectories[0].id, "p0-d0.2-a000");
        assert_eq!(plan.trajectories[1].id, "p0-d0.2-a030");
        assert_eq!(plan.trajectories[12].id, "p0-d0.4-a000");
        assert_eq!(plan.trajectories[48].id, "p1-d0.2-a000");
        assert_eq!(plan.trajectories[239].id, "p4-d0.8-a330");
        assert_eq!(plan.waypoint_count(), 240 * 8);
    }

    #[test]
    fn waypoints_follow_the_stages() {
        let plan = sim_plan();
        let t = plan
            .trajectories
            .iter()
            .find(|t| t.id == "p4-d0.8-a090")
            .unwrap();
        let down = t.stage(StageName::Down).unwrap();
        // Surface at z = 0.2 m, point (3, 2) mm, approach 2 mm.
        let [a, b] = [down.waypoints[0], down.waypoints[1]];
        assert!((a.x - 0.403).abs() < 1e-12 && (a.y - 0.002).abs() < 1e-12);
        assert!((a.z - 0.202).abs() < 1e-12);
        assert!((b.z - 0.1992).abs() < 1e-12);
        // Shear at 90°: +y by 2 mm.
        let shear = t.stage(StageName::Shear).unwrap();
        assert!((shear.waypoints[1].y - 0.004).abs() < 1e-12);
        assert!((shear.waypoints[1].z - 0.1992).abs() < 1e-12);
        // Tool down everywhere.
        let down_pose = Pose::new(0.0, 0.0, 0.0, PI, 0.0, 0.0);
        for s in &t.stages {
            for w in &s.waypoints {
                assert!(rotation_distance(w, &down_pose) < 1e-12);
            }
        }
        let reverse = t.stage(StageName::Reverse).unwrap();
        assert_eq!(reverse.waypoints[1], shear.waypoints[0]);
        let up = t.stage(StageName::Up).unwrap();
        assert_eq!(up.waypoints[1], down.waypoints[0]);
    }

    #[test]
    fn envelope_violation_names_trajectory_stage_and_limit() {
        let mut c = RigConfig::sim_source();
        c.safety.envelope.min_z = 0.1993; // above the 0.8 mm depth (z = 0.1992)
        let e = Plan::build(&c, &Indenter::builtin("cone").unwrap()).unwrap_err();
        let first = &e.violations()[0];
        assert_eq!(first.trajectory, "p0-d0.8-a000");
        assert_eq!(first.stage, StageName::Down);
        assert_eq!(first.waypoint, 1);
        assert_eq!(
            e.to_string(),
            "unsafe plan: trajectory p0-d0.8-a000, stage down, waypoint 1: z = 0.1992 m is below \
             safety.envelope.min_z = 0.1993 m (and 359 more waypoints outside the limits)"
        );
    }

    #[test]
    fn tilted_surface_frames_are_followed() {
        let mut c = RigConfig::sim_source();
        // Gel facing +x (normal along base +x): rotate the frame 90° about y.
        c.sensor.surface_frame = Pose::new(0.4, 0.0, 0.2, 0.0, PI / 2.0, 0.0);
        c.safety.envelope = Envelope {
            min_x: 0.39,
            max_x: 0.41,
            min_y: -0.02,
            max_y: 0.02,
            min_z: 0.18,
            max_z: 0.22,
        };
        let plan = Plan::build(&c, &Indenter::builtin("cone").unwrap()).unwrap();
        let t = &plan.trajectories[3]; // p0-d0.2-a090
        let down = t.stage(StageName::Down).unwrap();
        // The approach is 2 mm out along +x, the press 0.2 mm into −x.
        assert!((down.waypoints[0].x - 0.402).abs() < 1e-12);
        assert!((down.waypoints[1].x - 0.3998).abs() < 1e-12);
        let margins = plan.envelope_margins(&c.safety.envelope);
        assert!((margins.max_x_mm - 8.0).abs() < 1e-9);
        // The depth check recomputes depth from the base-frame pose along the tilted normal:
        // checking the same plan against a shallower limit flags exactly the deeper waypoints.
        c.safety.max_depth_mm = 0.7;
        let e = plan.check(&c).unwrap_err();
        let v = e.violations();
        assert_eq!(v.len(), 60 * 6); // 0.8 mm trajectories, 6 stage waypoints at depth each
        assert!(v.iter().all(|v| v.trajectory.contains("-d0.8-")));
        assert!(
            v[0].reason
                .starts_with("depth 0.8000 mm exceeds safety.max_depth_mm = 0.7 mm"),
            "{}",
            v[0]
        );
    }

    #[test]
    fn stage_durations_use_a_trapezoid() {
        // 2.2 mm at 1 mm/s, 10 mm/s²: 2.2 + 0.1 s.
        assert!((trapezoid_time_s(2.2, 1.0, 10.0) - 2.3).abs() < 1e-12);
        // Too short to reach the speed: 2 √(L/a).
        assert!((trapezoid_time_s(0.05, 1.0, 10.0) - 2.0 * 0.005f64.sqrt()).abs() < 1e-12);
        let plan = sim_plan();
        let t = &plan.trajectories[0];
        assert!((t.stage(StageName::Down).unwrap().duration_estimate_s() - 2.3).abs() < 1e-9);
    }

    #[test]
    fn invalid_config_is_refused_before_planning() {
        let mut c = RigConfig::sim_source();
        c.plan.depths_mm = vec![0.2, 1.5];
        let e = Plan::build(&c, &Indenter::builtin("cone").unwrap()).unwrap_err();
        assert!(e.to_string().contains("plan.depths_mm[1]"), "{e}");
    }
}
