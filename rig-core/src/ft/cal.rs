//! ATI calibration files (`.cal`, XML) and the calibration they describe.
//!
//! # Format (ATI "ATIDAQFT" / F/T calibration file, as shipped on the sensor's CD)
//!
//! ```text
//! <FTSensor Serial="FT12345" BodyStyle="Nano17" Family="DAQ" NumGages="6" CalFileVersion="1.1">
//!   <Calibration PartNumber="SI-25-0.25" CalDate="..." ForceUnits="N" TorqueUnits="N-mm"
//!                DistUnits="mm" AngleUnits="degrees" ...>
//!     <Axis Name="Fx" values="g1 g2 g3 g4 g5 g6" max="25" scale="…"/>   × 6 (Fx..Tz)
//!     <BasicTransform Dx="0" Dy="0" Dz="…" Rx="0" Ry="0" Rz="0"/>
//!     <UserAxis Name="Fx" values="…" max="25"/>                         × 6, optional
//!     <BiasSlope values="…"/> <GainSlope values="…"/> <Thermistor value="…"/>  optional
//!   </Calibration>
//! </FTSensor>
//! ```
//!
//! - **Matrix**: rows Fx, Fy, Fz, Tx, Ty, Tz; columns the six gauges; entries in the file's force
//!   and torque units per gauge volt. When `UserAxis` rows are present they are the working
//!   matrix, already at the file's reporting point. Otherwise (older files) the matrix is derived:
//!   each `Axis` row's `values` divided by its `scale`, then moved by the `BasicTransform`
//!   (a [`ToolTransform`] with `Dx..Dz` in `DistUnits`, `Rx..Rz` in `AngleUnits`). Where both
//!   exist they agree; [`Calibration::derivation_mismatch`] reports by how much.
//! - **Units** are converted to N and N·mm ([`force_unit_to_n`], [`torque_unit_to_nmm`]):
//!   N, lbf, kgf, kN; N·mm, N·m, lbf·in, lbf·ft, kgf·cm. Max loads are converted the same way.
//! - **Temperature compensation** (when `BiasSlope`, `GainSlope` and `Thermistor` are present),
//!   per gauge, with the thermistor reading `T` and its value at calibration `T0`:
//!   `G' = (G + bs·(T − T0)) / (1 − gs·(T − T0))`.
//! - **Output range** (`OutputRange`, `OutputBipolar` on `<Calibration>`): the span of the
//!   sensor's gauge outputs in volts, bipolar by default (`OutputRange="20"`: ±10 V; some
//!   amplifiers give ±5 V). A DAQ card's input range is set from it ([`OutputRange`]); a gauge
//!   within 0.5 % of either end counts as saturated ([`OutputRange::saturated_gauges`], ATI's
//!   convention in its DAQ F/T C library). Without the attributes: ±[`GAUGE_RANGE_V`].
//!
//! Errors name the element and attribute (`<Axis Name="Fz"> attribute values: ...`). A singular
//! matrix is an error; an ill-conditioned one (condition number above
//! [`ILL_CONDITIONED_LIMIT`], computed with each row scaled by its max load so that N and N·mm
//! rows compare) is accepted but reported by [`Calibration::conditioning`].

use std::path::Path;

use nalgebra::{Matrix6, Vector6};

use super::transform::{ToolTransform, TransformError, condition_number};
use super::{AXES, saturation_mask};

/// A calibration whose scaled condition number exceeds this is reported as ill-conditioned.
/// ATI matrices of healthy sensors sit around 1-30 by this measure.
pub const ILL_CONDITIONED_LIMIT: f64 = 1e3;
/// Above this scaled condition number the matrix is treated as singular (not invertible in
/// double precision for this purpose).
pub const SINGULAR_LIMIT: f64 = 1e12;
/// Full-scale input of the DAQ front ends ATI pairs with a Nano17 (±10 V); a gauge at or beyond
/// this is saturated.
pub const GAUGE_RANGE_V: f64 = 10.0;

/// ATI's DAQ F/T library treats a gauge reading as saturated beyond this fraction of the
/// input range.
pub const SATURATION_FRACTION: f64 = 0.995;

/// The span of the sensor's gauge outputs, volts (`OutputRange` / `OutputBipolar`).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct OutputRange {
    pub min_v: f64,
    pub max_v: f64,
}

impl Default for OutputRange {
    /// ±[`GAUGE_RANGE_V`].
    fn default() -> Self {
        Self {
            min_v: -GAUGE_RANGE_V,
            max_v: GAUGE_RANGE_V,
        }
    }
}

impl OutputRange {
    /// Bit i set when gauge i is within 0.5 % of either end of the range, or not finite
    /// ([`SATURATION_FRACTION`]).
    pub fn saturated_gauges(&self, gauges_v: &[f64; 6]) -> u8 {
        let mid = 0.5 * (self.max_v + self.min_v);
        let half = 0.5 * (self.max_v - self.min_v) * SATURATION_FRACTION;
        let mut mask = 0u8;
        for (i, g) in gauges_v.iter().enumerate() {
            if !g.is_finite() || (g - mid).abs() >= half {
                mask |= 1 << i;
            }
        }
        mask
    }
}

/// Why a calibration file could not be used. Messages name the element and attribute.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CalError {
    #[error("cannot read calibration file {path}: {reason}")]
    Io { path: String, reason: String },
    #[error("calibration file is not well-formed XML: {0}")]
    Xml(String),
    #[error("calibration file: {element}: {reason}")]
    Element { element: String, reason: String },
    #[error(
        "calibration file: {element}: the matrix is singular (scaled condition number {condition:.3e}); the file is damaged or not a 6-axis calibration"
    )]
    Singular { element: String, condition: f64 },
}

fn elem_err(element: impl Into<String>, reason: impl Into<String>) -> CalError {
    CalError::Element {
        element: element.into(),
        reason: reason.into(),
    }
}

/// Where the working matrix came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum MatrixSource {
    /// The file's `UserAxis` rows.
    UserAxis,
    /// `Axis` values / scale moved by the `BasicTransform`.
    AxisBasicTransform,
}

/// Temperature compensation data of a calibration.
#[derive(Debug, Clone, PartialEq)]
pub struct TemperatureCompensation {
    /// Per-gauge bias slope `bs` (V per thermistor unit).
    pub bias_slope: [f64; 6],
    /// Per-gauge gain slope `gs` (per thermistor unit).
    pub gain_slope: [f64; 6],
    /// Thermistor reading at calibration, `T0` (V).
    pub thermistor_ref: f64,
}

impl TemperatureCompensation {
    /// `G' = (G + bs·(T − T0)) / (1 − gs·(T − T0))`. `None` when the denominator vanishes or
    /// `T` is not finite.
    pub fn compensate(&self, gauges_v: &[f64; 6], thermistor: f64) -> Option<[f64; 6]> {
        if !thermistor.is_finite() {
            return None;
        }
        let dt = thermistor - self.thermistor_ref;
        let mut out = [0.0; 6];
        for i in 0..6 {
            let den = 1.0 - self.gain_slope[i] * dt;
            if den.abs() < 1e-9 {
                return None;
            }
            out[i] = (gauges_v[i] + self.bias_slope[i] * dt) / den;
        }
        Some(out)
    }

    /// The inverse of [`Self::compensate`]: raw gauges that compensate to `compensated`.
    pub fn uncompensate(&self, compensated: &[f64; 6], thermistor: f64) -> [f64; 6] {
        let dt = thermistor - self.thermistor_ref;
        let mut out = [0.0; 6];
        for i in 0..6 {
            out[i] = compensated[i] * (1.0 - self.gain_slope[i] * dt) - self.bias_slope[i] * dt;
        }
        out
    }
}

/// How well-conditioned a calibration matrix is.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Conditioning {
    /// 2-norm condition number of the matrix in N and N·mm per volt.
    pub condition_number: f64,
    /// The same with each row divided by its max load (unit-independent).
    pub scaled_condition_number: f64,
    /// `scaled_condition_number > ILL_CONDITIONED_LIMIT`.
    pub ill_conditioned: bool,
}

/// A parsed, converted and checked calibration.
#[derive(Debug, Clone, PartialEq)]
pub struct Calibration {
    pub serial: String,
    pub body_style: String,
    pub family: String,
    pub part_number: String,
    pub cal_date: String,
    /// Units as written in the file (before conversion).
    pub file_force_units: String,
    pub file_torque_units: String,
    /// Working matrix: rows Fx..Tz in N and N·mm per gauge volt.
    pub matrix: Matrix6<f64>,
    /// Where [`Self::matrix`] came from.
    pub source: MatrixSource,
    /// The matrix derived from `Axis` / scale and the `BasicTransform` (always present).
    pub derived_matrix: Matrix6<f64>,
    /// Max loads, N and N·mm.
    pub max_loads: [f64; 6],
    /// The file's basic transform (displacement in mm, angles in radians).
    pub basic_transform_mm_rad: [f64; 6],
    pub temperature: Option<TemperatureCompensation>,
    /// The gauges' output span (`OutputRange`, `OutputBipolar`), ±10 V when not given.
    pub output_range: OutputRange,
    inverse: Matrix6<f64>,
    conditioning: Conditioning,
}

/// Conversion factor from a `.cal` force unit to newtons.
pub fn force_unit_to_n(unit: &str) -> Option<f64> {
    Some(match unit.trim().to_ascii_lowercase().as_str() {
        "n" => 1.0,
        "kn" => 1000.0,
        "mn" => 1e-3,
        "lb" | "lbf" => 4.448_221_615_260_5,
        "klb" | "klbf" => 4_448.221_615_260_5,
        "kg" | "kgf" => 9.806_65,
        "g" | "gf" => 9.806_65e-3,
        _ => return None,
    })
}

/// Conversion factor from a `.cal` torque unit to N·mm.
pub fn torque_unit_to_nmm(unit: &str) -> Option<f64> {
    let u = unit
        .trim()
        .to_ascii_lowercase()
        .replace(['·', '*', ' '], "-");
    Some(match u.as_str() {
        "n-mm" | "nmm" => 1.0,
        "n-m" | "nm" => 1000.0,
        "kn-m" => 1e6,
        "lb-in" | "lbf-in" | "in-lb" | "in-lbf" => 112.984_829_027_616_7,
        "lb-ft" | "lbf-ft" | "ft-lb" | "ft-lbf" => 1_355.817_948_331_4,
        "kg-cm" | "kgf-cm" => 98.066_5,
        "kg-m" | "kgf-m" => 9806.65,
        "g-cm" | "gf-cm" => 0.098_066_5,
        _ => return None,
    })
}

/// Conversion factor from a `.cal` distance unit to mm.
pub fn dist_unit_to_mm(unit: &str) -> Option<f64> {
    Some(match unit.trim().to_ascii_lowercase().as_str() {
        "mm" => 1.0,
        "cm" => 10.0,
        "m" => 1000.0,
        "in" => 25.4,
        "ft" => 304.8,
        _ => return None,
    })
}

fn angle_unit_to_rad(unit: &str) -> Option<f64> {
    Some(match unit.trim().to_ascii_lowercase().as_str() {
        "degrees" | "degree" | "deg" => std::f64::consts::PI / 180.0,
        "radians" | "radian" | "rad" => 1.0,
        _ => return None,
    })
}

fn describe(node: roxmltree::Node) -> String {
    match node.attribute("Name") {
        Some(n) => format!("<{} Name=\"{n}\">", node.tag_name().name()),
        None => format!("<{}>", node.tag_name().name()),
    }
}

fn attr<'a>(node: roxmltree::Node<'a, '_>, name: &str) -> Result<&'a str, CalError> {
    node.attribute(name)
        .ok_or_else(|| elem_err(describe(node), format!("missing attribute `{name}`")))
}

/// `text` as a finite number, or an error naming the element and attribute.
fn finite_number(node: roxmltree::Node, name: &str, text: &str) -> Result<f64, CalError> {
    let v: f64 = text.trim().parse().map_err(|_| {
        elem_err(
            describe(node),
            format!("attribute `{name}`: {text:?} is not a number"),
        )
    })?;
    if !v.is_finite() {
        return Err(elem_err(
            describe(node),
            format!("attribute `{name}`: {text:?} is not finite"),
        ));
    }
    Ok(v)
}

/// A row's `max` attribute (its axis's rated load), which must be positive.
fn row_max(node: roxmltree::Node) -> Result<f64, CalError> {
    let max = attr_f64(node, "max")?;
    if max <= 0.0 {
        return Err(elem_err(
            describe(node),
            format!("attribute `max` = {max} must be positive"),
        ));
    }
    Ok(max)
}

fn attr_f64(node: roxmltree::Node, name: &str) -> Result<f64, CalError> {
    finite_number(node, name, attr(node, name)?)
}

fn attr_f64_or(node: roxmltree::Node, name: &str, default: f64) -> Result<f64, CalError> {
    if node.attribute(name).is_some() {
        attr_f64(node, name)
    } else {
        Ok(default)
    }
}

fn attr_values6(node: roxmltree::Node, name: &str) -> Result<[f64; 6], CalError> {
    let s = attr(node, name)?;
    let mut out = [0.0; 6];
    let mut n = 0;
    for tok in s
        .split(|c: char| c.is_whitespace() || c == ',')
        .filter(|t| !t.is_empty())
    {
        let v = finite_number(node, name, tok)?;
        if n < 6 {
            out[n] = v;
        }
        n += 1;
    }
    if n != 6 {
        return Err(elem_err(
            describe(node),
            format!("attribute `{name}` has {n} numbers, expected 6 (one per gauge)"),
        ));
    }
    Ok(out)
}

/// Six rows named Fx..Tz among the children `tag` of `cal`, in axis order.
fn axis_rows<'a, 'i>(
    cal: roxmltree::Node<'a, 'i>,
    tag: &str,
) -> Result<Option<[roxmltree::Node<'a, 'i>; 6]>, CalError> {
    let nodes: Vec<_> = cal
        .children()
        .filter(|n| n.is_element() && n.tag_name().name() == tag)
        .collect();
    if nodes.is_empty() {
        return Ok(None);
    }
    let mut rows: [Option<roxmltree::Node>; 6] = [None; 6];
    for n in &nodes {
        let name = attr(*n, "Name")?;
        let Some(i) = AXES
            .iter()
            .position(|a| a.eq_ignore_ascii_case(name.trim()))
        else {
            return Err(elem_err(
                describe(*n),
                format!("unknown axis name {name:?} (expected one of Fx, Fy, Fz, Tx, Ty, Tz)"),
            ));
        };
        if rows[i].is_some() {
            return Err(elem_err(describe(*n), format!("axis {name} appears twice")));
        }
        rows[i] = Some(*n);
    }
    let mut out = [nodes[0]; 6];
    for i in 0..6 {
        out[i] = rows[i].ok_or_else(|| {
            elem_err(
                format!("<{tag} Name=\"{}\">", AXES[i]),
                format!("missing: a calibration needs six <{tag}> rows, Fx..Tz"),
            )
        })?;
    }
    Ok(Some(out))
}

impl Calibration {
    /// Reads and parses a `.cal` file.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, CalError> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|e| CalError::Io {
            path: path.display().to_string(),
            reason: e.to_string(),
        })?;
        Self::parse(&text)
    }

    /// Parses the XML text of a `.cal` file. See the module docs.
    pub fn parse(xml: &str) -> Result<Self, CalError> {
        let doc = roxmltree::Document::parse(xml).map_err(|e| CalError::Xml(e.to_string()))?;
        let root = doc.root_element();
        if root.tag_name().name() != "FTSensor" {
            return Err(elem_err(
                format!("<{}>", root.tag_name().name()),
                "the root element must be <FTSensor>",
            ));
        }
        if let Some(g) = root.attribute("NumGages")
            && g.trim() != "6"
        {
            return Err(elem_err(
                "<FTSensor>",
                format!("attribute `NumGages` = {g:?}: only 6-gauge sensors are supported"),
            ));
        }
        let cal = root
            .children()
            .find(|n| n.is_element() && n.tag_name().name() == "Calibration")
            .ok_or_else(|| elem_err("<FTSensor>", "missing child element <Calibration>"))?;

        let fu = attr(cal, "ForceUnits")?;
        let tu = attr(cal, "TorqueUnits")?;
        // Each unit attribute's factor to N, N·mm, mm or rad, or an error listing what is known.
        type ToSi = fn(&str) -> Option<f64>;
        let units: [(&str, &str, ToSi, &str); 4] = [
            (
                "ForceUnits",
                fu,
                force_unit_to_n,
                "a known unit (N, lbf, kgf, kN)",
            ),
            (
                "TorqueUnits",
                tu,
                torque_unit_to_nmm,
                "a known unit (N-mm, N-m, lbf-in, lbf-ft, kgf-cm)",
            ),
            (
                "DistUnits",
                cal.attribute("DistUnits").unwrap_or("mm"),
                dist_unit_to_mm,
                "a known unit (mm, cm, m, in, ft)",
            ),
            (
                "AngleUnits",
                cal.attribute("AngleUnits").unwrap_or("degrees"),
                angle_unit_to_rad,
                "degrees or radians",
            ),
        ];
        let mut factors = [0.0; 4];
        for (k, (name, value, to_si, known)) in factors.iter_mut().zip(units) {
            *k = to_si(value).ok_or_else(|| {
                elem_err(
                    "<Calibration>",
                    format!("attribute `{name}` = {value:?} is not {known}"),
                )
            })?;
        }
        let [f_k, t_k, d_k, a_k] = factors;
        let unit = |i: usize| if i < 3 { f_k } else { t_k };

        // Axis rows (required): values / scale, converted.
        let axis = axis_rows(cal, "Axis")?
            .ok_or_else(|| elem_err("<Calibration>", "missing the six <Axis> rows"))?;
        let mut basic = Matrix6::zeros();
        let mut max_loads = [0.0; 6];
        for (i, node) in axis.iter().enumerate() {
            let values = attr_values6(*node, "values")?;
            let scale = attr_f64_or(*node, "scale", 1.0)?;
            if scale == 0.0 {
                return Err(elem_err(describe(*node), "attribute `scale` is zero"));
            }
            for j in 0..6 {
                basic[(i, j)] = values[j] / scale * unit(i);
            }
            max_loads[i] = row_max(*node)? * unit(i);
        }

        let mut bt = [0.0; 6];
        if let Some(node) = cal
            .children()
            .find(|n| n.is_element() && n.tag_name().name() == "BasicTransform")
        {
            for (k, name) in ["Dx", "Dy", "Dz", "Rx", "Ry", "Rz"].iter().enumerate() {
                let v = attr_f64_or(node, name, 0.0)?;
                bt[k] = v * if k < 3 { d_k } else { a_k };
            }
        }
        let transform = ToolTransform::from_angles([bt[0], bt[1], bt[2]], [bt[3], bt[4], bt[5]])
            .map_err(|e: TransformError| elem_err("<BasicTransform>", e.to_string()))?;
        let derived = transform.matrix() * basic;

        let (matrix, source) = match axis_rows(cal, "UserAxis")? {
            Some(rows) => {
                let mut m = Matrix6::zeros();
                for (i, node) in rows.iter().enumerate() {
                    let values = attr_values6(*node, "values")?;
                    for j in 0..6 {
                        m[(i, j)] = values[j] * unit(i);
                    }
                    if node.attribute("max").is_some() {
                        max_loads[i] = row_max(*node)? * unit(i);
                    }
                }
                (m, MatrixSource::UserAxis)
            }
            None => (derived, MatrixSource::AxisBasicTransform),
        };

        let temperature = parse_temperature(cal)?;
        let output_range = parse_output_range(cal)?;

        let conditioning = conditioning_of(&matrix, &max_loads);
        let element = match source {
            MatrixSource::UserAxis => "<UserAxis> rows",
            MatrixSource::AxisBasicTransform => "<Axis> rows",
        };
        let inverse = match matrix.try_inverse() {
            Some(inv) if conditioning.scaled_condition_number < SINGULAR_LIMIT => inv,
            _ => {
                return Err(CalError::Singular {
                    element: element.to_owned(),
                    condition: conditioning.scaled_condition_number,
                });
            }
        };

        let s = |n: &str| root.attribute(n).unwrap_or("").to_owned();
        Ok(Self {
            serial: s("Serial"),
            body_style: s("BodyStyle"),
            family: s("Family"),
            part_number: cal.attribute("PartNumber").unwrap_or("").to_owned(),
            cal_date: cal.attribute("CalDate").unwrap_or("").to_owned(),
            file_force_units: fu.to_owned(),
            file_torque_units: tu.to_owned(),
            matrix,
            source,
            derived_matrix: derived,
            max_loads,
            basic_transform_mm_rad: bt,
            temperature,
            output_range,
            inverse,
            conditioning,
        })
    }

    /// Builds a calibration from a matrix (N, N·mm per volt) and max loads, e.g. for a
    /// simulated sensor. Fails when the matrix is singular.
    pub fn from_matrix(matrix: Matrix6<f64>, max_loads: [f64; 6]) -> Result<Self, CalError> {
        let conditioning = conditioning_of(&matrix, &max_loads);
        let inverse = matrix
            .try_inverse()
            .filter(|_| conditioning.scaled_condition_number < SINGULAR_LIMIT)
            .ok_or(CalError::Singular {
                element: "matrix".to_owned(),
                condition: conditioning.scaled_condition_number,
            })?;
        Ok(Self {
            serial: String::new(),
            body_style: String::new(),
            family: String::new(),
            part_number: String::new(),
            cal_date: String::new(),
            file_force_units: "N".to_owned(),
            file_torque_units: "N-mm".to_owned(),
            matrix,
            source: MatrixSource::UserAxis,
            derived_matrix: matrix,
            max_loads,
            basic_transform_mm_rad: [0.0; 6],
            temperature: None,
            output_range: OutputRange::default(),
            inverse,
            conditioning,
        })
    }

    /// Condition numbers of the working matrix.
    pub fn conditioning(&self) -> Conditioning {
        self.conditioning
    }

    /// Largest relative difference between the `UserAxis` matrix and the one derived from
    /// `Axis` / scale and the `BasicTransform`, per element, relative to the largest entry of
    /// its row. `None` when the file has no `UserAxis` rows.
    pub fn derivation_mismatch(&self) -> Option<f64> {
        if self.source != MatrixSource::UserAxis {
            return None;
        }
        let mut worst: f64 = 0.0;
        for i in 0..6 {
            let row_max = (0..6)
                .map(|j| self.matrix[(i, j)].abs())
                .fold(0.0, f64::max)
                .max(f64::MIN_POSITIVE);
            for j in 0..6 {
                let d = (self.matrix[(i, j)] - self.derived_matrix[(i, j)]).abs() / row_max;
                worst = worst.max(d);
            }
        }
        Some(worst)
    }

    /// Temperature-compensated gauges (unchanged when the file has no compensation data or no
    /// thermistor reading is given). The bool is false when compensation was possible in
    /// principle but the thermistor reading was unusable.
    pub fn compensate(&self, gauges_v: &[f64; 6], thermistor_v: Option<f64>) -> ([f64; 6], bool) {
        match (&self.temperature, thermistor_v) {
            (Some(tc), Some(t)) => match tc.compensate(gauges_v, t) {
                Some(g) => (g, true),
                None => (*gauges_v, false),
            },
            _ => (*gauges_v, true),
        }
    }

    /// `F = M · (V − bias)`, V and bias in volts (already compensated), F in N and N·mm.
    pub fn wrench(&self, gauges_v: &[f64; 6], bias_v: &[f64; 6]) -> [f64; 6] {
        let mut v = Vector6::zeros();
        for i in 0..6 {
            v[i] = gauges_v[i] - bias_v[i];
        }
        (self.matrix * v).into()
    }

    /// The gauge voltages (compensated, without bias) that read as `wrench`: `M⁻¹ F`.
    pub fn gauges_for(&self, wrench: &[f64; 6]) -> [f64; 6] {
        (self.inverse * Vector6::from_column_slice(wrench)).into()
    }

    /// Axes at or beyond their max load (bit i = axis i).
    pub fn saturated_axes(&self, wrench: &[f64; 6]) -> u8 {
        saturation_mask(wrench, &self.max_loads)
    }
}

fn conditioning_of(m: &Matrix6<f64>, max_loads: &[f64; 6]) -> Conditioning {
    let condition_number = condition_number(m);
    let mut scaled = *m;
    for i in 0..6 {
        let s = if max_loads[i] > 0.0 {
            max_loads[i]
        } else {
            1.0
        };
        for j in 0..6 {
            scaled[(i, j)] /= s;
        }
    }
    let scaled_condition_number = condition_number_of(&scaled);
    Conditioning {
        condition_number,
        scaled_condition_number,
        ill_conditioned: scaled_condition_number.is_nan()
            || scaled_condition_number > ILL_CONDITIONED_LIMIT,
    }
}

fn condition_number_of(m: &Matrix6<f64>) -> f64 {
    condition_number(m)
}

/// `OutputRange` (a positive span in volts) and `OutputBipolar` (`True`: centred on 0 V, the
/// default; `False`: 0 V up to the span).
fn parse_output_range(cal: roxmltree::Node) -> Result<OutputRange, CalError> {
    let Some(text) = cal.attribute("OutputRange") else {
        return Ok(OutputRange::default());
    };
    let span = finite_number(cal, "OutputRange", text)?;
    if span <= 0.0 {
        return Err(elem_err(
            "<Calibration>",
            format!("attribute `OutputRange` = {text:?} must be a positive span in volts"),
        ));
    }
    let bipolar = match cal.attribute("OutputBipolar").map(str::trim) {
        None => true,
        Some(b) if b.eq_ignore_ascii_case("true") => true,
        Some(b) if b.eq_ignore_ascii_case("false") => false,
        Some(b) => {
            return Err(elem_err(
                "<Calibration>",
                format!("attribute `OutputBipolar` = {b:?} is not True or False"),
            ));
        }
    };
    Ok(if bipolar {
        OutputRange {
            min_v: -span / 2.0,
            max_v: span / 2.0,
        }
    } else {
        OutputRange {
            min_v: 0.0,
            max_v: span,
        }
    })
}

fn parse_temperature(cal: roxmltree::Node) -> Result<Option<TemperatureCompensation>, CalError> {
    let find = |tag: &str| {
        cal.children()
            .find(|n| n.is_element() && n.tag_name().name() == tag)
    };
    let (bs, gs, th) = (find("BiasSlope"), find("GainSlope"), find("Thermistor"));
    match (bs, gs, th) {
        (None, None, None) => Ok(None),
        (Some(bs), Some(gs), Some(th)) => Ok(Some(TemperatureCompensation {
            bias_slope: attr_values6(bs, "values")?,
            gain_slope: attr_values6(gs, "values")?,
            thermistor_ref: attr_f64(th, "value")?,
        })),
        _ => {
            let missing: Vec<&str> = [
                ("<BiasSlope>", bs),
                ("<GainSlope>", gs),
                ("<Thermistor>", th),
            ]
            .iter()
            .filter(|(_, n)| n.is_none())
            .map(|(t, _)| *t)
            .collect();
            Err(elem_err(
                missing.join(", "),
                "missing: temperature compensation needs <BiasSlope>, <GainSlope> and <Thermistor> together",
            ))
        }
    }
}
