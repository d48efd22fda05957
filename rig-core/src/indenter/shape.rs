//! Parametric contact-face primitives and their gap functions.
//!
//! Every primitive describes the downward-facing contact face of (part of) an indenter as a *gap*
//! function `g(x, y)` in mm: how far the face lies above the primitive's own lowest point, at the
//! horizontal position `(x, y)`. `g ≥ 0`, `g = 0` is reached somewhere inside the primitive, and
//! `f64::INFINITY` means "no material above this point" (nothing there can touch the gel).
//!
//! A [`Shape`] places a primitive: `center_mm` (offset from the indenter axis), `rotation_deg`
//! (about the indenter axis, counter-clockwise seen from above the gel, i.e. looking along the
//! pressing direction from behind the indenter) and `lift_mm` (how far its lowest point sits above
//! the indenter's datum). An indenter is the union of its shapes: its gap is the minimum of the
//! shapes' gaps, shifted so that the lowest point of the whole face is 0.
//!
//! Local frame of every primitive: x along its length/first axis, y across, both in mm.

use serde::{Deserialize, Serialize};

/// Cross-section of bars and dots.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum Profile {
    /// A flat end face (flat punch): gap 0 over the whole footprint.
    #[default]
    Flat,
    /// A circular cross-section (a cylinder lying on its side for bars, a hemisphere for dots):
    /// radius = half the width.
    Round,
}

/// Sphere cap: `g = R − √(R² − ρ²)` for `ρ ≤ rim_radius_mm`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SphereCap {
    /// Sphere radius R.
    pub radius_mm: f64,
    /// Radius of the cap's rim (where the sphere meets the indenter body); at most R. Default: R
    /// (a full hemisphere).
    #[serde(default)]
    pub rim_radius_mm: Option<f64>,
}

/// Right circular cone, tip down: `g = ρ / tan α` for `ρ ≤ radius_mm`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Cone {
    /// Semi-angle α between the axis and the flank, degrees, in (0, 90).
    pub semi_angle_deg: f64,
    /// Base radius of the cone.
    pub radius_mm: f64,
}

/// Flat circular punch: `g = 0` for `ρ ≤ radius_mm`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FlatPunch {
    pub radius_mm: f64,
}

/// Flat annulus (the end face of a cylindrical shell): `g = 0` for `inner ≤ ρ ≤ outer`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Ring {
    pub outer_radius_mm: f64,
    pub inner_radius_mm: f64,
}

/// Torus lying flat: `g = r − √(r² − (ρ − R)²)` for `|ρ − R| ≤ r`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Torus {
    /// Distance R from the axis to the centre of the tube.
    pub major_radius_mm: f64,
    /// Tube radius r (< R).
    pub minor_radius_mm: f64,
}

/// Flat regular polygon (a prism extrusion seen end-on), first vertex on local +x.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Polygon {
    /// Number of sides, ≥ 3.
    pub sides: u32,
    /// Distance from the centre to each vertex.
    pub circumradius_mm: f64,
}

/// `count` parallel bars along local x, `pitch_mm` apart (centred on the y axis), each
/// `length_mm` × `width_mm`, with a flat or round cross-section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Bars {
    #[serde(default = "one")]
    pub count: u32,
    /// Centre-to-centre distance; required when `count > 1`.
    #[serde(default)]
    pub pitch_mm: f64,
    pub length_mm: f64,
    pub width_mm: f64,
    #[serde(default)]
    pub profile: Profile,
}

fn one() -> u32 {
    1
}

/// Ridge with a triangular cross-section (a prism lying on an edge) along local x:
/// `g = |y| / tan(half_angle)` for `|x| ≤ length/2`, `|y| ≤ width/2`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Wedge {
    pub length_mm: f64,
    pub width_mm: f64,
    /// Half the included angle of the edge, degrees, in (0, 90).
    pub half_angle_deg: f64,
}

/// Rectangular grid of `rows` × `cols` dots, `pitch_mm` apart, centred on the origin.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DotGrid {
    pub rows: u32,
    pub cols: u32,
    pub pitch_mm: f64,
    /// Radius of each dot; at most half the pitch.
    pub dot_radius_mm: f64,
    /// `flat` pins or `round` (hemispherical) dots.
    #[serde(default)]
    pub profile: Profile,
}

/// Corrugated rectangle: `g = A (1 − cos(2π x / λ)) / 2` over `size_mm`, crests (g = 0) at
/// `x = k λ`, crests running along local y.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Wave {
    /// Extent `[x, y]` of the corrugated face.
    pub size_mm: [f64; 2],
    pub wavelength_mm: f64,
    /// Crest-to-trough height A.
    pub amplitude_mm: f64,
}

/// Flat crescent: a disc of `radius_mm` minus a disc of `cut_radius_mm` centred at
/// `(cut_offset_mm, 0)`; the crescent's back is towards −x.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Moon {
    pub radius_mm: f64,
    pub cut_radius_mm: f64,
    pub cut_offset_mm: f64,
}

/// Flat disc with a wedge-shaped mouth of `mouth_deg` opening towards +x.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Pacman {
    pub radius_mm: f64,
    pub mouth_deg: f64,
}

/// `count` hemispherical bumps at reproducible pseudo-random places (from `seed`) inside a disc of
/// `area_radius_mm`, radii in `[radius_min_mm, radius_max_mm]`, each lifted by a random amount in
/// `[0, max_lift_mm]` (the first bump is never lifted, so the lowest point is 0).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RandomBumps {
    pub count: u32,
    pub seed: u64,
    pub area_radius_mm: f64,
    pub radius_min_mm: f64,
    pub radius_max_mm: f64,
    #[serde(default)]
    pub max_lift_mm: f64,
}

/// One primitive, tagged by `kind` in TOML (`kind = "sphere_cap"`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Primitive {
    SphereCap(SphereCap),
    Cone(Cone),
    FlatPunch(FlatPunch),
    Ring(Ring),
    Torus(Torus),
    Polygon(Polygon),
    Bars(Bars),
    Wedge(Wedge),
    DotGrid(DotGrid),
    Wave(Wave),
    Moon(Moon),
    Pacman(Pacman),
    RandomBumps(RandomBumps),
}

/// Names of the primitive kinds, as written in TOML.
pub const PRIMITIVE_KINDS: [&str; 13] = [
    "sphere_cap",
    "cone",
    "flat_punch",
    "ring",
    "torus",
    "polygon",
    "bars",
    "wedge",
    "dot_grid",
    "wave",
    "moon",
    "pacman",
    "random_bumps",
];

/// A placed primitive (see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct Shape {
    pub primitive: Primitive,
    /// Offset of the primitive's origin from the indenter axis, `[x, y]`.
    pub center_mm: [f64; 2],
    /// Rotation about the indenter axis.
    pub rotation_deg: f64,
    /// Height of the primitive's lowest point above the indenter datum, ≥ 0.
    pub lift_mm: f64,
    /// Bumps of a `random_bumps` primitive, generated once from its seed.
    bumps: Vec<Bump>,
    cos: f64,
    sin: f64,
    /// `1/tan` of a cone's semi-angle or a wedge's half-angle (the gap per mm off the tip or
    /// ridge), once: the contact solver asks for the gap many times a step.
    flank: f64,
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct Bump {
    x: f64,
    y: f64,
    radius: f64,
    lift: f64,
}

impl Shape {
    /// Places a primitive after checking its parameters; `Err((key, reason))` names the offending
    /// parameter relative to the shape (`radius_mm`, say).
    pub fn new(
        primitive: Primitive,
        center_mm: [f64; 2],
        rotation_deg: f64,
        lift_mm: f64,
    ) -> Result<Self, (String, String)> {
        check_primitive(&primitive)?;
        if !(center_mm[0].is_finite() && center_mm[1].is_finite()) {
            return Err(("center_mm".into(), "must be finite numbers".into()));
        }
        if !rotation_deg.is_finite() {
            return Err(("rotation_deg".into(), "must be a finite number".into()));
        }
        non_negative("lift_mm", lift_mm)?;
        let bumps = match &primitive {
            Primitive::RandomBumps(r) => generate_bumps(r),
            _ => Vec::new(),
        };
        let (sin, cos) = rotation_deg.to_radians().sin_cos();
        let flank = match &primitive {
            Primitive::Cone(p) => 1.0 / p.semi_angle_deg.to_radians().tan(),
            Primitive::Wedge(p) => 1.0 / p.half_angle_deg.to_radians().tan(),
            _ => 0.0,
        };
        Ok(Self {
            primitive,
            center_mm,
            rotation_deg,
            lift_mm,
            bumps,
            cos,
            sin,
            flank,
        })
    }

    /// Gap of this shape at `(x, y)` mm in the indenter frame, including `lift_mm`.
    pub fn gap_mm(&self, x: f64, y: f64) -> f64 {
        let (u, v) = self.local(x, y);
        self.lift_mm + self.local_gap(u, v)
    }

    /// `(x, y)` mm in the indenter frame, in the primitive's frame: about its centre, rotated
    /// by −rotation.
    fn local(&self, x: f64, y: f64) -> (f64, f64) {
        let dx = x - self.center_mm[0];
        let dy = y - self.center_mm[1];
        (
            self.cos * dx + self.sin * dy,
            -self.sin * dx + self.cos * dy,
        )
    }

    /// Half-extents `[x, y]` of the axis-aligned box (in the indenter frame) that holds the shape.
    pub fn half_extents_mm(&self) -> [f64; 2] {
        let [hx, hy] = local_half_extents(&self.primitive);
        let (c, s) = (self.cos.abs(), self.sin.abs());
        [
            self.center_mm[0].abs() + c * hx + s * hy,
            self.center_mm[1].abs() + s * hx + c * hy,
        ]
    }

    /// The face near its edge, at `(x, y)` mm in the indenter frame: `(gap, distance)`, the
    /// gap of the face's nearest point (including `lift_mm`) and the signed distance to the
    /// footprint's edge, positive inside. The contact's overlap filters the edge with it
    /// (`hardware-mocks`' `sim/contact`), so a wall passing a sub-sample moves the overlap
    /// continuously. Outside the footprint the gap is the face's at the edge: where the edge
    /// is a wall (flat faces, a cap's rim), that is the top of the wall. `None` for random
    /// bumps, whose rims are not pressed.
    pub fn edge_mm(&self, x: f64, y: f64) -> Option<(f64, f64)> {
        let (u, v) = self.local(x, y);
        let rho = radius(u, v);
        let (gap, distance) = match &self.primitive {
            Primitive::SphereCap(p) => {
                let rim = p.rim_radius_mm.unwrap_or(p.radius_mm);
                (cap(p.radius_mm, rho.min(rim)), rim - rho)
            }
            Primitive::Cone(p) => (rho.min(p.radius_mm) * self.flank, p.radius_mm - rho),
            Primitive::FlatPunch(p) => (0.0, p.radius_mm - rho),
            Primitive::Ring(p) => (0.0, (rho - p.inner_radius_mm).min(p.outer_radius_mm - rho)),
            Primitive::Torus(p) => {
                let off = (rho - p.major_radius_mm).abs();
                (cap(p.minor_radius_mm, off), p.minor_radius_mm - off)
            }
            Primitive::Polygon(p) => {
                let n = f64::from(p.sides);
                let apothem = p.circumradius_mm * (std::f64::consts::PI / n).cos();
                let sector = std::f64::consts::TAU / n;
                let off = v.atan2(u).rem_euclid(sector) - sector / 2.0;
                // The distance to the nearest side's line (the corners are rounded off by it).
                (0.0, apothem - rho * off.cos())
            }
            Primitive::Bars(p) => {
                let half_w = p.width_mm / 2.0;
                let first = -(f64::from(p.count) - 1.0) / 2.0 * p.pitch_mm;
                let dv = nearest_offset(v, first, p.pitch_mm, p.count);
                let gap = match p.profile {
                    Profile::Flat => 0.0,
                    Profile::Round => cap(half_w, dv),
                };
                (gap, (half_w - dv).min(p.length_mm / 2.0 - u.abs()))
            }
            Primitive::Wedge(p) => (
                v.abs().min(p.width_mm / 2.0) * self.flank,
                (p.length_mm / 2.0 - u.abs()).min(p.width_mm / 2.0 - v.abs()),
            ),
            Primitive::DotGrid(p) => {
                let fx = -(f64::from(p.cols) - 1.0) / 2.0 * p.pitch_mm;
                let fy = -(f64::from(p.rows) - 1.0) / 2.0 * p.pitch_mm;
                let r = radius(
                    nearest_offset(u, fx, p.pitch_mm, p.cols),
                    nearest_offset(v, fy, p.pitch_mm, p.rows),
                );
                let gap = match p.profile {
                    Profile::Flat => 0.0,
                    Profile::Round => cap(p.dot_radius_mm, r),
                };
                (gap, p.dot_radius_mm - r)
            }
            Primitive::Wave(p) => {
                let uu = u.clamp(-p.size_mm[0] / 2.0, p.size_mm[0] / 2.0);
                (
                    p.amplitude_mm * (1.0 - (std::f64::consts::TAU * uu / p.wavelength_mm).cos())
                        / 2.0,
                    (p.size_mm[0] / 2.0 - u.abs()).min(p.size_mm[1] / 2.0 - v.abs()),
                )
            }
            Primitive::Moon(p) => (
                0.0,
                (p.radius_mm - rho).min(radius(u - p.cut_offset_mm, v) - p.cut_radius_mm),
            ),
            Primitive::Pacman(p) => {
                // The mouth's two sides are rays from the centre at ±mouth/2: a point's
                // distance from the nearer one, negative inside the mouth.
                let beyond = v.atan2(u).abs() - p.mouth_deg.to_radians() / 2.0;
                let side = if beyond < std::f64::consts::FRAC_PI_2 {
                    rho * beyond.sin()
                } else {
                    rho
                };
                (0.0, (p.radius_mm - rho).min(side))
            }
            Primitive::RandomBumps(_) => return None,
        };
        Some((self.lift_mm + gap, distance))
    }

    fn local_gap(&self, u: f64, v: f64) -> f64 {
        const NONE: f64 = f64::INFINITY;
        let rho = radius(u, v);
        match &self.primitive {
            Primitive::SphereCap(p) => {
                let rim = p.rim_radius_mm.unwrap_or(p.radius_mm);
                if rho <= rim {
                    cap(p.radius_mm, rho)
                } else {
                    NONE
                }
            }
            Primitive::Cone(p) => {
                if rho <= p.radius_mm {
                    rho * self.flank
                } else {
                    NONE
                }
            }
            Primitive::FlatPunch(p) => {
                if rho <= p.radius_mm {
                    0.0
                } else {
                    NONE
                }
            }
            Primitive::Ring(p) => {
                if rho >= p.inner_radius_mm && rho <= p.outer_radius_mm {
                    0.0
                } else {
                    NONE
                }
            }
            Primitive::Torus(p) => {
                let off = (rho - p.major_radius_mm).abs();
                if off <= p.minor_radius_mm {
                    cap(p.minor_radius_mm, off)
                } else {
                    NONE
                }
            }
            Primitive::Polygon(p) => {
                let n = f64::from(p.sides);
                let apothem = p.circumradius_mm * (std::f64::consts::PI / n).cos();
                // Edge normals sit half-way between vertices (first vertex on +x), at
                // (k + ½)·2π/n; the point is inside when its projection on the normal nearest
                // its own direction is within the apothem (the farthest projection of all).
                let sector = std::f64::consts::TAU / n;
                let off = v.atan2(u).rem_euclid(sector) - sector / 2.0;
                if rho * off.cos() <= apothem + 1e-12 {
                    0.0
                } else {
                    NONE
                }
            }
            Primitive::Bars(p) => {
                if u.abs() > p.length_mm / 2.0 {
                    return NONE;
                }
                let half_w = p.width_mm / 2.0;
                let first = -(f64::from(p.count) - 1.0) / 2.0 * p.pitch_mm;
                let dv = nearest_offset(v, first, p.pitch_mm, p.count);
                if dv > half_w {
                    NONE
                } else {
                    match p.profile {
                        Profile::Flat => 0.0,
                        Profile::Round => cap(half_w, dv),
                    }
                }
            }
            Primitive::Wedge(p) => {
                if u.abs() <= p.length_mm / 2.0 && v.abs() <= p.width_mm / 2.0 {
                    v.abs() * self.flank
                } else {
                    NONE
                }
            }
            Primitive::DotGrid(p) => {
                let fx = -(f64::from(p.cols) - 1.0) / 2.0 * p.pitch_mm;
                let fy = -(f64::from(p.rows) - 1.0) / 2.0 * p.pitch_mm;
                let du = nearest_offset(u, fx, p.pitch_mm, p.cols);
                let dv = nearest_offset(v, fy, p.pitch_mm, p.rows);
                let r = radius(du, dv);
                if r > p.dot_radius_mm {
                    NONE
                } else {
                    match p.profile {
                        Profile::Flat => 0.0,
                        Profile::Round => cap(p.dot_radius_mm, r),
                    }
                }
            }
            Primitive::Wave(p) => {
                if u.abs() <= p.size_mm[0] / 2.0 && v.abs() <= p.size_mm[1] / 2.0 {
                    p.amplitude_mm * (1.0 - (std::f64::consts::TAU * u / p.wavelength_mm).cos())
                        / 2.0
                } else {
                    NONE
                }
            }
            Primitive::Moon(p) => {
                let in_disc = rho <= p.radius_mm;
                let in_cut = radius(u - p.cut_offset_mm, v) < p.cut_radius_mm;
                if in_disc && !in_cut { 0.0 } else { NONE }
            }
            Primitive::Pacman(p) => {
                let in_mouth = rho > 0.0 && v.atan2(u).abs().to_degrees() < p.mouth_deg / 2.0;
                if rho <= p.radius_mm && !in_mouth {
                    0.0
                } else {
                    NONE
                }
            }
            Primitive::RandomBumps(_) => self
                .bumps
                .iter()
                .filter_map(|b| {
                    let r = radius(u - b.x, v - b.y);
                    (r <= b.radius).then(|| b.lift + cap(b.radius, r))
                })
                .fold(NONE, f64::min),
        }
    }
}

/// Height of a sphere of radius `r` above its lowest point at horizontal distance `d` (≤ r).
fn cap(r: f64, d: f64) -> f64 {
    let d = d.min(r);
    // r − √(r² − d²) written as d² / (r + √(r² − d²)): no cancellation near d = 0.
    let s = ((r - d) * (r + d)).max(0.0).sqrt();
    d * d / (r + s)
}

/// Distance from `x` to the nearest of `count` points `first + k · pitch`.
fn nearest_offset(x: f64, first: f64, pitch: f64, count: u32) -> f64 {
    if count <= 1 || pitch <= 0.0 {
        return (x - first).abs();
    }
    let k = ((x - first) / pitch)
        .round()
        .clamp(0.0, f64::from(count - 1));
    (x - (first + k * pitch)).abs()
}

/// `√(u² + v²)`. The gap is sampled many times a step (the contact's sub-sampled overlap), and
/// `f64::hypot`'s guard against overflow costs several square roots; coordinates here are
/// millimetres within an indenter's footprint, far from overflow.
fn radius(u: f64, v: f64) -> f64 {
    (u * u + v * v).sqrt()
}

fn local_half_extents(p: &Primitive) -> [f64; 2] {
    match p {
        Primitive::SphereCap(p) => {
            let r = p.rim_radius_mm.unwrap_or(p.radius_mm);
            [r, r]
        }
        Primitive::Cone(p) => [p.radius_mm; 2],
        Primitive::FlatPunch(p) => [p.radius_mm; 2],
        Primitive::Ring(p) => [p.outer_radius_mm; 2],
        Primitive::Torus(p) => [p.major_radius_mm + p.minor_radius_mm; 2],
        Primitive::Polygon(p) => [p.circumradius_mm; 2],
        Primitive::Bars(p) => [
            p.length_mm / 2.0,
            ((f64::from(p.count) - 1.0) * p.pitch_mm + p.width_mm) / 2.0,
        ],
        Primitive::Wedge(p) => [p.length_mm / 2.0, p.width_mm / 2.0],
        Primitive::DotGrid(p) => [
            (f64::from(p.cols) - 1.0) * p.pitch_mm / 2.0 + p.dot_radius_mm,
            (f64::from(p.rows) - 1.0) * p.pitch_mm / 2.0 + p.dot_radius_mm,
        ],
        Primitive::Wave(p) => [p.size_mm[0] / 2.0, p.size_mm[1] / 2.0],
        Primitive::Moon(p) => [p.radius_mm; 2],
        Primitive::Pacman(p) => [p.radius_mm; 2],
        Primitive::RandomBumps(p) => [p.area_radius_mm + p.radius_max_mm; 2],
    }
}

type Check = Result<(), (String, String)>;

fn positive(key: &str, x: f64) -> Check {
    if x.is_finite() && x > 0.0 {
        Ok(())
    } else {
        Err((key.into(), format!("{x} must be a finite number > 0")))
    }
}

fn angle_in_open_quadrant(key: &str, deg: f64) -> Check {
    if deg.is_finite() && deg > 0.0 && deg < 90.0 {
        Ok(())
    } else {
        Err((
            key.into(),
            format!("{deg}° must be strictly between 0° and 90°"),
        ))
    }
}

fn fail(key: &str, reason: String) -> Check {
    Err((key.into(), reason))
}

fn non_negative(key: &str, x: f64) -> Check {
    if x.is_finite() && x >= 0.0 {
        Ok(())
    } else {
        fail(key, format!("{x} must be finite and ≥ 0"))
    }
}

/// `x` mm must be strictly below `limit_key` = `limit` mm.
fn below(key: &str, x: f64, limit_key: &str, limit: f64) -> Check {
    if x < limit {
        Ok(())
    } else {
        fail(
            key,
            format!("{x} mm must be below {limit_key} = {limit} mm"),
        )
    }
}

/// `x` mm may not exceed `limit_key` = `limit` mm; `why` (with a leading space, or empty) says
/// what would go wrong.
fn not_above(key: &str, x: f64, limit_key: &str, limit: f64, why: &str) -> Check {
    if x > limit {
        fail(key, format!("{x} mm exceeds {limit_key} = {limit} mm{why}"))
    } else {
        Ok(())
    }
}

/// Checks a primitive's parameters so that its gap function is well defined and reaches 0.
fn check_primitive(p: &Primitive) -> Check {
    match p {
        Primitive::SphereCap(p) => {
            positive("radius_mm", p.radius_mm)?;
            if let Some(rim) = p.rim_radius_mm {
                positive("rim_radius_mm", rim)?;
                not_above("rim_radius_mm", rim, "radius_mm", p.radius_mm, "")?;
            }
        }
        Primitive::Cone(p) => {
            angle_in_open_quadrant("semi_angle_deg", p.semi_angle_deg)?;
            positive("radius_mm", p.radius_mm)?;
        }
        Primitive::FlatPunch(p) => positive("radius_mm", p.radius_mm)?,
        Primitive::Ring(p) => {
            positive("outer_radius_mm", p.outer_radius_mm)?;
            non_negative("inner_radius_mm", p.inner_radius_mm)?;
            below(
                "inner_radius_mm",
                p.inner_radius_mm,
                "outer_radius_mm",
                p.outer_radius_mm,
            )?;
        }
        Primitive::Torus(p) => {
            positive("major_radius_mm", p.major_radius_mm)?;
            positive("minor_radius_mm", p.minor_radius_mm)?;
            below(
                "minor_radius_mm",
                p.minor_radius_mm,
                "major_radius_mm",
                p.major_radius_mm,
            )?;
        }
        Primitive::Polygon(p) => {
            if p.sides < 3 {
                return fail("sides", format!("{} must be at least 3", p.sides));
            }
            positive("circumradius_mm", p.circumradius_mm)?;
        }
        Primitive::Bars(p) => {
            if p.count == 0 {
                return fail("count", "must be at least 1".into());
            }
            positive("length_mm", p.length_mm)?;
            positive("width_mm", p.width_mm)?;
            if p.count > 1 {
                positive("pitch_mm", p.pitch_mm)?;
                not_above(
                    "width_mm",
                    p.width_mm,
                    "pitch_mm",
                    p.pitch_mm,
                    " (bars would merge)",
                )?;
            }
        }
        Primitive::Wedge(p) => {
            positive("length_mm", p.length_mm)?;
            positive("width_mm", p.width_mm)?;
            angle_in_open_quadrant("half_angle_deg", p.half_angle_deg)?;
        }
        Primitive::DotGrid(p) => {
            if p.rows == 0 || p.cols == 0 {
                return fail("rows", "rows and cols must be at least 1".into());
            }
            positive("dot_radius_mm", p.dot_radius_mm)?;
            if p.rows > 1 || p.cols > 1 {
                positive("pitch_mm", p.pitch_mm)?;
                if 2.0 * p.dot_radius_mm > p.pitch_mm {
                    return fail(
                        "dot_radius_mm",
                        format!(
                            "{} mm exceeds half of pitch_mm = {} mm (dots would merge)",
                            p.dot_radius_mm, p.pitch_mm
                        ),
                    );
                }
            }
        }
        Primitive::Wave(p) => {
            positive("size_mm[0]", p.size_mm[0])?;
            positive("size_mm[1]", p.size_mm[1])?;
            positive("wavelength_mm", p.wavelength_mm)?;
            positive("amplitude_mm", p.amplitude_mm)?;
        }
        Primitive::Moon(p) => {
            positive("radius_mm", p.radius_mm)?;
            positive("cut_radius_mm", p.cut_radius_mm)?;
            if !p.cut_offset_mm.is_finite() {
                return fail("cut_offset_mm", "must be a finite number".into());
            }
            // The crescent must keep some of the disc: the cut disc may not cover it.
            if p.cut_radius_mm >= p.radius_mm + p.cut_offset_mm.abs() {
                return fail(
                    "cut_radius_mm",
                    format!(
                        "{} mm cuts away the whole disc (needs < radius_mm + |cut_offset_mm| = {} mm)",
                        p.cut_radius_mm,
                        p.radius_mm + p.cut_offset_mm.abs()
                    ),
                );
            }
        }
        Primitive::Pacman(p) => {
            positive("radius_mm", p.radius_mm)?;
            if !(p.mouth_deg.is_finite() && p.mouth_deg >= 0.0 && p.mouth_deg < 360.0) {
                return fail("mouth_deg", format!("{}° must be in [0, 360)", p.mouth_deg));
            }
        }
        Primitive::RandomBumps(p) => {
            if p.count == 0 || p.count > 10_000 {
                return fail("count", format!("{} must be in 1..=10000", p.count));
            }
            positive("area_radius_mm", p.area_radius_mm)?;
            positive("radius_min_mm", p.radius_min_mm)?;
            positive("radius_max_mm", p.radius_max_mm)?;
            not_above(
                "radius_min_mm",
                p.radius_min_mm,
                "radius_max_mm",
                p.radius_max_mm,
                "",
            )?;
            non_negative("max_lift_mm", p.max_lift_mm)?;
        }
    }
    Ok(())
}

/// SplitMix64: a tiny, well-known 64-bit generator; enough for reproducible bump layouts, and
/// stable across platforms and releases (unlike a library RNG whose stream may change).
struct SplitMix64(u64);

impl SplitMix64 {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    fn next_f64(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
}

fn generate_bumps(p: &RandomBumps) -> Vec<Bump> {
    let mut rng = SplitMix64(p.seed);
    (0..p.count)
        .map(|i| {
            // Uniform over the disc: radius ∝ √u.
            let r = p.area_radius_mm * rng.next_f64().sqrt();
            let theta = std::f64::consts::TAU * rng.next_f64();
            let radius = p.radius_min_mm + (p.radius_max_mm - p.radius_min_mm) * rng.next_f64();
            let lift = if i == 0 {
                0.0
            } else {
                p.max_lift_mm * rng.next_f64()
            };
            Bump {
                x: r * theta.cos(),
                y: r * theta.sin(),
                radius,
                lift,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cap_is_accurate_near_the_apex() {
        assert_eq!(cap(2.0, 0.0), 0.0);
        let d = 1e-6;
        assert!((cap(2.0, d) - d * d / 4.0).abs() < 1e-20);
        assert!((cap(2.0, 2.0) - 2.0).abs() < 1e-12);
    }

    #[test]
    fn random_bumps_are_reproducible() {
        let p = RandomBumps {
            count: 5,
            seed: 3,
            area_radius_mm: 4.0,
            radius_min_mm: 0.5,
            radius_max_mm: 1.0,
            max_lift_mm: 0.2,
        };
        assert_eq!(generate_bumps(&p), generate_bumps(&p));
        assert_eq!(generate_bumps(&p)[0].lift, 0.0);
    }

    #[test]
    fn polygon_contains_its_centre_and_not_its_outside() {
        let s = Shape::new(
            Primitive::Polygon(Polygon {
                sides: 3,
                circumradius_mm: 2.0,
            }),
            [0.0, 0.0],
            0.0,
            0.0,
        )
        .unwrap();
        assert_eq!(s.gap_mm(0.0, 0.0), 0.0);
        assert_eq!(s.gap_mm(1.9, 0.0), 0.0);
        assert!(s.gap_mm(-1.1, 0.0).is_infinite()); // apothem is 1.0
    }
}
