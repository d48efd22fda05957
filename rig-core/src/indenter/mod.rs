//! Indenters: the rigid tips the robot presses into the gel, described by their contact face.
//!
//! Only the downward-facing contact face matters to the rig and the simulator, so an indenter is
//! a *gap field*: at each horizontal position `(x, y)` (mm, indenter axis at the origin, axes
//! aligned with the TCP's x/y, which the plan aligns with the sensor surface frame's x/y), the
//! height of the face above its lowest point (the tip, which is the TCP). See [`Heightmap`] for
//! the sampled form and its "no material" marker (`f64::INFINITY`).
//!
//! Two sources:
//!
//! - **Parametric TOML** (`indenters/<name>.toml`): a list of placed primitives
//!   (see [`shape`]: sphere cap, cone, flat punch, ring, torus, regular polygon, bars, wedge,
//!   dot grid, wave, moon, pacman, random bumps) whose union is the face. Any resolution can be
//!   generated. The 19 built-in indenters (the paper's 18 plus `paralines`) are embedded in the
//!   binary, so `rig` works from any directory.
//! - **STL** (binary or ASCII), directly (`my_tip.stl`: contact face towards −z, axis at the
//!   centre of the x/y bounding box, mm) or through a TOML file with an `[stl]` table giving
//!   `path`, `tip = "-z" | "+z"`, `centre = "bbox" | "origin"` and `mm_per_unit`.
//!
//! The built-in dimensions are assumptions: the public STLs of this indenter family have a
//! 16 × 16 mm footprint and are 20 mm tall, and each file says what was assumed for its face.
//!
//! TOML format:
//!
//! ```toml
//! name = "cone"                      # filename-safe; must match the file name for built-ins
//! description = "Right circular cone, 60° semi-angle"
//! footprint_mm = [16.0, 16.0]        # optional, default [16, 16]; every shape must fit in it
//! height_mm = 20.0                   # optional, default 20
//!
//! [[shape]]
//! kind = "cone"                      # one of shape::PRIMITIVE_KINDS
//! semi_angle_deg = 60.0
//! radius_mm = 6.0
//! center_mm = [0.0, 0.0]             # optional placement, default centred
//! rotation_deg = 0.0                 # optional, about the axis
//! lift_mm = 0.0                      # optional, height of this shape's lowest point
//! ```

pub mod heightmap;
pub mod shape;
pub mod stl;

use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::config::ids::{is_id, is_id_char};

pub use heightmap::{GridError, Heightmap};
pub use shape::{Primitive, Shape};
pub use stl::{Centre, Mesh, StlOptions, TipDirection};

/// Default footprint of an indenter, mm (the family's public STLs: 16 × 16 mm).
pub const DEFAULT_FOOTPRINT_MM: [f64; 2] = [16.0, 16.0];
/// Default height of an indenter, mm (the family's public STLs: 20 mm).
pub const DEFAULT_HEIGHT_MM: f64 = 20.0;

macro_rules! builtins {
    ($($name:literal),* $(,)?) => {
        /// Names and embedded TOML of the built-in indenters.
        const BUILTINS: &[(&str, &str)] = &[
            $(($name, include_str!(concat!("../../../indenters/", $name, ".toml")))),*
        ];
        /// Names of the built-in indenters, in listing order.
        pub const BUILTIN_NAMES: &[&str] = &[$($name),*];
    };
}

builtins!(
    "cone",
    "cylinder",
    "cylinder_sh",
    "cylinder_si",
    "dotin",
    "dots",
    "hemisphere",
    "hexagon",
    "line",
    "moon",
    "pacman",
    "prism",
    "random",
    "sphere",
    "sphere_s",
    "torus",
    "triangle",
    "wave",
    "paralines",
);

/// Why an indenter could not be loaded or sampled.
#[derive(Debug, thiserror::Error)]
pub enum IndenterError {
    #[error(
        "unknown indenter `{name}`; built-in indenters are: {}; or give a path to a .toml or .stl file",
        .known.join(", ")
    )]
    Unknown { name: String, known: Vec<String> },
    #[error("cannot read indenter file {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("indenter {origin}: {message}")]
    Toml { origin: String, message: String },
    #[error("indenter {origin}: {key}: {reason}")]
    Invalid {
        origin: String,
        key: String,
        reason: String,
    },
    #[error("indenter {origin}: STL: {reason}")]
    Stl { origin: String, reason: String },
    #[error(transparent)]
    Grid(#[from] GridError),
}

/// What an indenter's face is made of.
#[derive(Debug, Clone, PartialEq)]
pub enum Geometry {
    /// Union of parametric shapes.
    Shapes(Vec<Shape>),
    /// A triangle mesh (from STL), tip at z = 0.
    Mesh(Mesh),
}

/// An indenter: a name, a description and the geometry of its contact face.
#[derive(Debug, Clone, PartialEq)]
pub struct Indenter {
    name: String,
    description: String,
    footprint_mm: [f64; 2],
    height_mm: f64,
    origin: String,
    geometry: Geometry,
    /// Lowest shape lift: subtracted so the face's lowest point is at gap 0.
    lowest_mm: f64,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct IndenterFile {
    name: String,
    #[serde(default)]
    description: String,
    #[serde(default)]
    footprint_mm: Option<[f64; 2]>,
    #[serde(default)]
    height_mm: Option<f64>,
    #[serde(default)]
    shape: Vec<toml::Table>,
    #[serde(default)]
    stl: Option<StlRef>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct StlRef {
    path: PathBuf,
    #[serde(default)]
    tip: TipDirection,
    #[serde(default)]
    centre: Centre,
    #[serde(default = "one")]
    mm_per_unit: f64,
}

fn one() -> f64 {
    1.0
}

impl Indenter {
    /// Loads a built-in indenter by name, or a file when the argument ends in `.toml` or `.stl`
    /// or contains a path separator.
    pub fn load(name_or_path: &str) -> Result<Self, IndenterError> {
        let lower = name_or_path.to_ascii_lowercase();
        let is_path = lower.ends_with(".toml")
            || lower.ends_with(".stl")
            || name_or_path.contains('/')
            || name_or_path.contains(std::path::MAIN_SEPARATOR);
        if is_path {
            Self::load_file(Path::new(name_or_path))
        } else {
            Self::builtin(name_or_path)
        }
    }

    /// A built-in indenter (embedded TOML); unknown names list the known ones.
    pub fn builtin(name: &str) -> Result<Self, IndenterError> {
        let Some((_, text)) = BUILTINS.iter().find(|(n, _)| *n == name) else {
            return Err(IndenterError::Unknown {
                name: name.to_owned(),
                known: BUILTIN_NAMES.iter().map(|s| (*s).to_owned()).collect(),
            });
        };
        Self::from_toml_str_at(text, &format!("<built-in {name}>"), None)
    }

    /// Names of the built-in indenters.
    pub fn list_builtin() -> &'static [&'static str] {
        BUILTIN_NAMES
    }

    /// Loads an indenter file: `.stl` as a mesh, anything else as indenter TOML.
    pub fn load_file(path: &Path) -> Result<Self, IndenterError> {
        let bytes = std::fs::read(path).map_err(|source| IndenterError::Io {
            path: path.to_owned(),
            source,
        })?;
        let origin = path.display().to_string();
        let is_stl = path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("stl"));
        if is_stl {
            let stem = path
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default();
            let name = sanitise_name(&stem);
            return Self::from_stl_bytes_at(&name, &bytes, StlOptions::default(), &origin);
        }
        let text = String::from_utf8(bytes).map_err(|_| IndenterError::Toml {
            origin: origin.clone(),
            message: "not UTF-8 text (an STL file needs the .stl extension)".into(),
        })?;
        Self::from_toml_str_at(&text, &origin, path.parent())
    }

    /// Parses indenter TOML held in a string; an `[stl]` path is relative to the working directory.
    pub fn from_toml_str(text: &str) -> Result<Self, IndenterError> {
        Self::from_toml_str_at(text, "<string>", None)
    }

    /// Builds an indenter from STL bytes.
    pub fn from_stl_bytes(
        name: &str,
        bytes: &[u8],
        options: StlOptions,
    ) -> Result<Self, IndenterError> {
        Self::from_stl_bytes_at(name, bytes, options, &format!("<stl {name}>"))
    }

    fn from_stl_bytes_at(
        name: &str,
        bytes: &[u8],
        options: StlOptions,
        origin: &str,
    ) -> Result<Self, IndenterError> {
        check_name(name, origin)?;
        let stl_err = |reason: String| IndenterError::Stl {
            origin: origin.to_owned(),
            reason,
        };
        let mesh = stl::parse(bytes)
            .and_then(|raw| Mesh::from_triangles(raw, options))
            .map_err(stl_err)?;
        let ([hx, hy], hz) = mesh.extents_mm();
        Ok(Self {
            name: name.to_owned(),
            description: format!("mesh from {origin}"),
            footprint_mm: [2.0 * hx, 2.0 * hy],
            height_mm: hz,
            origin: origin.to_owned(),
            geometry: Geometry::Mesh(mesh),
            lowest_mm: 0.0,
        })
    }

    fn from_toml_str_at(
        text: &str,
        origin: &str,
        base_dir: Option<&Path>,
    ) -> Result<Self, IndenterError> {
        let file: IndenterFile = toml::from_str(text).map_err(|e| IndenterError::Toml {
            origin: origin.to_owned(),
            message: match e.span() {
                Some(span) => format!(
                    "line {}: {}",
                    text[..span.start.min(text.len())].matches('\n').count() + 1,
                    e.message().trim()
                ),
                None => e.message().trim().to_owned(),
            },
        })?;
        let invalid = |key: &str, reason: String| IndenterError::Invalid {
            origin: origin.to_owned(),
            key: key.to_owned(),
            reason,
        };
        check_name(&file.name, origin)?;
        let footprint = file.footprint_mm.unwrap_or(DEFAULT_FOOTPRINT_MM);
        if !footprint.iter().all(|x| x.is_finite() && *x > 0.0) {
            return Err(invalid(
                "footprint_mm",
                format!("{footprint:?} must be two finite numbers > 0"),
            ));
        }
        let height = file.height_mm.unwrap_or(DEFAULT_HEIGHT_MM);
        if !(height.is_finite() && height > 0.0) {
            return Err(invalid(
                "height_mm",
                format!("{height} must be a finite number > 0"),
            ));
        }

        match (file.shape.is_empty(), file.stl) {
            (false, Some(_)) => Err(invalid(
                "stl",
                "give either [[shape]] tables or an [stl] table, not both".into(),
            )),
            (true, None) => Err(invalid(
                "shape",
                format!(
                    "no geometry: add [[shape]] tables (kinds: {}) or an [stl] table",
                    shape::PRIMITIVE_KINDS.join(", ")
                ),
            )),
            (true, Some(stl_ref)) => {
                let path = match base_dir {
                    Some(dir) if stl_ref.path.is_relative() => dir.join(&stl_ref.path),
                    _ => stl_ref.path.clone(),
                };
                let bytes = std::fs::read(&path).map_err(|source| IndenterError::Io {
                    path: path.clone(),
                    source,
                })?;
                let opts = StlOptions {
                    tip: stl_ref.tip,
                    centre: stl_ref.centre,
                    mm_per_unit: stl_ref.mm_per_unit,
                };
                let mut ind = Self::from_stl_bytes_at(
                    &file.name,
                    &bytes,
                    opts,
                    &format!("{origin} (stl.path {})", path.display()),
                )?;
                ind.origin = origin.to_owned();
                if !file.description.is_empty() {
                    ind.description = file.description;
                }
                if let Some(fp) = file.footprint_mm {
                    ind.footprint_mm = fp;
                }
                if let Some(h) = file.height_mm {
                    ind.height_mm = h;
                }
                Ok(ind)
            }
            (false, None) => {
                let mut shapes = Vec::with_capacity(file.shape.len());
                for (i, table) in file.shape.into_iter().enumerate() {
                    let key = format!("shape[{i}]");
                    let shape = parse_shape(table).map_err(|(k, reason)| {
                        invalid(
                            &if k.is_empty() {
                                key.clone()
                            } else {
                                format!("{key}.{k}")
                            },
                            reason,
                        )
                    })?;
                    let [hx, hy] = shape.half_extents_mm();
                    let tol = 1e-9;
                    if hx > footprint[0] / 2.0 + tol || hy > footprint[1] / 2.0 + tol {
                        return Err(invalid(
                            &key,
                            format!(
                                "reaches ±{hx:.3} mm in x and ±{hy:.3} mm in y, outside footprint_mm = [{}, {}]",
                                footprint[0], footprint[1]
                            ),
                        ));
                    }
                    shapes.push(shape);
                }
                let lowest = shapes
                    .iter()
                    .map(|s| s.lift_mm)
                    .fold(f64::INFINITY, f64::min);
                Ok(Self {
                    name: file.name,
                    description: file.description,
                    footprint_mm: footprint,
                    height_mm: height,
                    origin: origin.to_owned(),
                    geometry: Geometry::Shapes(shapes),
                    lowest_mm: lowest,
                })
            }
        }
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    /// One-line description of the face.
    pub fn description(&self) -> &str {
        &self.description
    }

    /// Outer size `[x, y]` of the indenter, mm.
    pub fn footprint_mm(&self) -> [f64; 2] {
        self.footprint_mm
    }

    /// Overall height of the indenter body, mm.
    pub fn height_mm(&self) -> f64 {
        self.height_mm
    }

    /// Where it was loaded from (`<built-in cone>`, a path, ...).
    pub fn origin(&self) -> &str {
        &self.origin
    }

    pub fn geometry(&self) -> &Geometry {
        &self.geometry
    }

    /// Gap of the contact face at `(x_mm, y_mm)`: height above the tip, or `INFINITY` where the
    /// indenter has no material (see [`Heightmap`]).
    pub fn gap_mm(&self, x_mm: f64, y_mm: f64) -> f64 {
        if !(x_mm.is_finite() && y_mm.is_finite()) {
            return f64::INFINITY;
        }
        match &self.geometry {
            Geometry::Shapes(shapes) => {
                shapes
                    .iter()
                    .map(|s| s.gap_mm(x_mm, y_mm))
                    .fold(f64::INFINITY, f64::min)
                    - self.lowest_mm
            }
            Geometry::Mesh(mesh) => mesh.gap_mm(x_mm, y_mm),
        }
    }

    /// The face near its edge at `(x_mm, y_mm)`: the gap of its nearest point and the signed
    /// distance to the footprint's edge, mm, positive inside ([`Shape::edge_mm`]); of several
    /// shapes, the one the point is deepest in (a union's signed distance is the largest).
    /// `None` for a mesh, or a shape that does not know its edge.
    pub fn edge_mm(&self, x_mm: f64, y_mm: f64) -> Option<(f64, f64)> {
        let Geometry::Shapes(shapes) = &self.geometry else {
            return None;
        };
        let mut best: Option<(f64, f64)> = None;
        for s in shapes {
            let (g, d) = s.edge_mm(x_mm, y_mm)?;
            if best.is_none_or(|(_, bd)| d > bd) {
                best = Some((g, d));
            }
        }
        best.map(|(g, d)| (g - self.lowest_mm, d))
    }

    /// The contact face sampled on a grid of `extent_mm` (total width in x and y) at
    /// `resolution_mm`, centred on the indenter axis.
    ///
    /// Panics on a non-positive or non-finite resolution or extent, or a grid above
    /// [`heightmap::MAX_CELLS`]: those are programming errors. For values from users, call
    /// [`Indenter::try_heightmap`].
    pub fn heightmap(&self, resolution_mm: f64, extent_mm: (f64, f64)) -> Heightmap {
        self.try_heightmap(resolution_mm, extent_mm)
            .unwrap_or_else(|e| panic!("Indenter::heightmap: {e}"))
    }

    /// As [`Indenter::heightmap`], with bad grid requests returned as errors.
    pub fn try_heightmap(
        &self,
        resolution_mm: f64,
        extent_mm: (f64, f64),
    ) -> Result<Heightmap, GridError> {
        let mut map = Heightmap::empty(resolution_mm, extent_mm)?;
        match &self.geometry {
            Geometry::Shapes(_) => {
                for iy in 0..map.ny {
                    let y = map.y_mm(iy);
                    for ix in 0..map.nx {
                        map.gap_mm[iy * map.nx + ix] = self.gap_mm(map.x_mm(ix), y);
                    }
                }
            }
            Geometry::Mesh(mesh) => mesh.rasterise(&mut map),
        }
        Ok(map)
    }
}

/// Splits a `[[shape]]` table into placement keys and the primitive, so both reject unknown keys.
fn parse_shape(mut table: toml::Table) -> Result<Shape, (String, String)> {
    fn take<T: serde::de::DeserializeOwned>(
        table: &mut toml::Table,
        key: &str,
        default: T,
    ) -> Result<T, (String, String)> {
        match table.remove(key) {
            None => Ok(default),
            Some(v) => v
                .try_into::<T>()
                .map_err(|e| (key.to_owned(), e.message().trim().to_owned())),
        }
    }
    let center = take(&mut table, "center_mm", [0.0, 0.0])?;
    let rotation = take(&mut table, "rotation_deg", 0.0)?;
    let lift = take(&mut table, "lift_mm", 0.0)?;
    if !table.contains_key("kind") {
        return Err((
            "kind".into(),
            format!("missing; one of: {}", shape::PRIMITIVE_KINDS.join(", ")),
        ));
    }
    let primitive: Primitive = toml::Value::Table(table)
        .try_into()
        .map_err(|e: toml::de::Error| (String::new(), e.message().trim().to_owned()))?;
    Shape::new(primitive, center, rotation, lift)
}

fn check_name(name: &str, origin: &str) -> Result<(), IndenterError> {
    let ok = !name.is_empty() && is_id(name);
    if ok {
        Ok(())
    } else {
        Err(IndenterError::Invalid {
            origin: origin.to_owned(),
            key: "name".into(),
            reason: format!(
                "{name:?} must be non-empty and use only letters, digits, '_', '-' and '.' (it names dataset files)"
            ),
        })
    }
}

fn sanitise_name(stem: &str) -> String {
    let s: String = stem
        .chars()
        .map(|c| if is_id_char(c) { c } else { '_' })
        .collect();
    if s.is_empty() { "stl".into() } else { s }
}
