//! A small STL reader (binary and ASCII) and the rasteriser that turns a mesh's downward-facing
//! surface into a gap field.
//!
//! Binary STL: an 80-byte header, a little-endian `u32` triangle count, then 50 bytes per
//! triangle (normal and three vertices as 12 `f32`, then a `u16` attribute). ASCII STL:
//! `solid …`, then per facet `facet normal nx ny nz` / `outer loop` / three `vertex x y z` /
//! `endloop` / `endfacet`, and `endsolid`. A binary file may also begin with `solid`, so a file
//! whose length matches its binary triangle count is read as binary first.
//!
//! Stored normals are ignored: the lowest surface is found by casting vertical rays.

use super::heightmap::Heightmap;

/// A triangle soup, mm, after orientation and centring (tip down at z = 0).
#[derive(Debug, Clone, PartialEq)]
pub struct Mesh {
    pub triangles: Vec<[[f64; 3]; 3]>,
}

/// Which way the indenter's contact face points in the STL file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub enum TipDirection {
    /// The contact face points to −z (the mesh is modelled as it hangs from the robot).
    #[default]
    #[serde(rename = "-z")]
    MinusZ,
    /// The contact face points to +z (the mesh stands on its base, as often modelled for
    /// printing); it is turned 180° about x.
    #[serde(rename = "+z")]
    PlusZ,
}

/// Where the indenter axis is in the STL file's x/y.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Centre {
    /// At the centre of the mesh's x/y bounding box.
    #[default]
    Bbox,
    /// At the file's x = y = 0.
    Origin,
}

/// How to read an STL file as an indenter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StlOptions {
    pub tip: TipDirection,
    pub centre: Centre,
    /// Millimetres per STL unit (1 for files in mm, 1000 for files in metres).
    pub mm_per_unit: f64,
}

impl Default for StlOptions {
    fn default() -> Self {
        Self {
            tip: TipDirection::MinusZ,
            centre: Centre::Bbox,
            mm_per_unit: 1.0,
        }
    }
}

/// Parses STL bytes into raw triangles (file units and orientation). `Err` says what is wrong.
pub fn parse(bytes: &[u8]) -> Result<Vec<[[f64; 3]; 3]>, String> {
    let binary_len = (bytes.len() >= 84).then(|| {
        let n = u32::from_le_bytes([bytes[80], bytes[81], bytes[82], bytes[83]]) as u64;
        (n, 84 + 50 * n)
    });
    let triangles = match binary_len {
        Some((_, expected)) if expected == bytes.len() as u64 => parse_binary(bytes)?,
        // A binary file whose header starts with "solid" but whose length is wrong is not text:
        // report the binary mismatch for it rather than a text decoding error.
        _ if looks_ascii(bytes) && std::str::from_utf8(bytes).is_ok() => parse_ascii(bytes)?,
        Some((n, expected)) => {
            return Err(format!(
                "not an ASCII STL (does not start with `solid`) and not a valid binary STL: the \
                 header announces {n} triangles ({expected} bytes) but the file has {} bytes",
                bytes.len()
            ));
        }
        None => {
            return Err(format!(
                "too short for a binary STL ({} bytes, the header alone is 84) and not an ASCII STL \
                 (does not start with `solid`)",
                bytes.len()
            ));
        }
    };
    if triangles.is_empty() {
        return Err("the file holds no triangles".into());
    }
    Ok(triangles)
}

fn looks_ascii(bytes: &[u8]) -> bool {
    let start = bytes
        .iter()
        .position(|b| !b.is_ascii_whitespace())
        .unwrap_or(bytes.len());
    bytes[start..].starts_with(b"solid")
}

fn parse_binary(bytes: &[u8]) -> Result<Vec<[[f64; 3]; 3]>, String> {
    let mut out = Vec::with_capacity((bytes.len() - 84) / 50);
    for (i, rec) in bytes[84..].chunks_exact(50).enumerate() {
        let f = |k: usize| {
            let o = 12 + 4 * k; // skip the normal
            f64::from(f32::from_le_bytes([
                rec[o],
                rec[o + 1],
                rec[o + 2],
                rec[o + 3],
            ]))
        };
        let tri = [[f(0), f(1), f(2)], [f(3), f(4), f(5)], [f(6), f(7), f(8)]];
        if tri.iter().flatten().any(|x| !x.is_finite()) {
            return Err(format!("triangle {i} has a non-finite vertex coordinate"));
        }
        out.push(tri);
    }
    Ok(out)
}

fn parse_ascii(bytes: &[u8]) -> Result<Vec<[[f64; 3]; 3]>, String> {
    let text = std::str::from_utf8(bytes)
        .map_err(|e| format!("ASCII STL is not valid UTF-8 text ({e})"))?;
    let mut out = Vec::new();
    let mut current: Option<Vec<[f64; 3]>> = None;
    for (n, line) in text.lines().enumerate() {
        let line_no = n + 1;
        let mut words = line.split_whitespace();
        let Some(word) = words.next() else { continue };
        match word {
            "solid" | "endsolid" | "outer" | "endloop" => {}
            "facet" => {
                if current.is_some() {
                    return Err(format!("line {line_no}: `facet` before `endfacet`"));
                }
                current = Some(Vec::with_capacity(3));
            }
            "vertex" => {
                let Some(facet) = current.as_mut() else {
                    return Err(format!("line {line_no}: `vertex` outside a facet"));
                };
                let mut v = [0.0; 3];
                for c in &mut v {
                    let w = words
                        .next()
                        .ok_or_else(|| format!("line {line_no}: `vertex` needs three numbers"))?;
                    *c = w
                        .parse::<f64>()
                        .ok()
                        .filter(|x| x.is_finite())
                        .ok_or_else(|| format!("line {line_no}: `{w}` is not a finite number"))?;
                }
                facet.push(v);
            }
            "endfacet" => {
                let facet = current
                    .take()
                    .ok_or_else(|| format!("line {line_no}: `endfacet` without `facet`"))?;
                if facet.len() != 3 {
                    return Err(format!(
                        "line {line_no}: facet has {} vertices, expected 3",
                        facet.len()
                    ));
                }
                out.push([facet[0], facet[1], facet[2]]);
            }
            other => {
                return Err(format!(
                    "line {line_no}: unexpected `{other}` (expected facet, outer loop, vertex, \
                     endloop, endfacet or endsolid)"
                ));
            }
        }
    }
    if current.is_some() {
        return Err("the last facet has no `endfacet` (file truncated?)".into());
    }
    Ok(out)
}

impl Mesh {
    /// Orients, scales and centres raw triangles per `opts`, then moves the lowest vertex to z = 0.
    pub fn from_triangles(raw: Vec<[[f64; 3]; 3]>, opts: StlOptions) -> Result<Self, String> {
        if !(opts.mm_per_unit.is_finite() && opts.mm_per_unit > 0.0) {
            return Err(format!(
                "mm_per_unit {} must be a finite number > 0",
                opts.mm_per_unit
            ));
        }
        let mut tris: Vec<[[f64; 3]; 3]> = raw
            .into_iter()
            .map(|t| {
                t.map(|[x, y, z]| {
                    let (x, y, z) = (
                        x * opts.mm_per_unit,
                        y * opts.mm_per_unit,
                        z * opts.mm_per_unit,
                    );
                    match opts.tip {
                        TipDirection::MinusZ => [x, y, z],
                        // 180° about x keeps the mesh right-handed (a mirror would not).
                        TipDirection::PlusZ => [x, -y, -z],
                    }
                })
            })
            .collect();
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for v in tris.iter().flatten() {
            for k in 0..3 {
                lo[k] = lo[k].min(v[k]);
                hi[k] = hi[k].max(v[k]);
            }
        }
        if lo.iter().chain(hi.iter()).any(|x| !x.is_finite()) {
            return Err("the mesh has no finite vertices".into());
        }
        let (cx, cy) = match opts.centre {
            Centre::Bbox => ((lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0),
            Centre::Origin => (0.0, 0.0),
        };
        for v in tris.iter_mut().flatten() {
            v[0] -= cx;
            v[1] -= cy;
            v[2] -= lo[2];
        }
        if !tris.iter().any(|t| projected_area2(t).abs() > 0.0) {
            return Err("no triangle has any extent seen from below (all faces vertical)".into());
        }
        Ok(Self { triangles: tris })
    }

    /// Half-extents `[x, y]` of the mesh around the axis, and its height, mm.
    pub fn extents_mm(&self) -> ([f64; 2], f64) {
        let mut hx: f64 = 0.0;
        let mut hy: f64 = 0.0;
        let mut hz: f64 = 0.0;
        for v in self.triangles.iter().flatten() {
            hx = hx.max(v[0].abs());
            hy = hy.max(v[1].abs());
            hz = hz.max(v[2]);
        }
        ([hx, hy], hz)
    }

    /// Height of the lowest surface at `(x, y)`; `INFINITY` where no triangle is above.
    pub fn gap_mm(&self, x: f64, y: f64) -> f64 {
        self.triangles
            .iter()
            .filter_map(|t| height_in_triangle(t, x, y))
            .fold(f64::INFINITY, f64::min)
    }

    /// Writes the lowest surface into `map` (cells start at INFINITY), one triangle at a time over
    /// the cells under its bounding box: cost proportional to the covered area, not cells × faces.
    pub fn rasterise(&self, map: &mut Heightmap) {
        let res = map.resolution_mm;
        let x0 = map.x_mm(0);
        let y0 = map.y_mm(0);
        let index_range = |lo: f64, hi: f64, origin: f64, n: usize| -> Option<(usize, usize)> {
            let a = ((lo - origin) / res).ceil().max(0.0);
            let b = ((hi - origin) / res).floor().min(n as f64 - 1.0);
            (a <= b).then_some((a as usize, b as usize))
        };
        for t in &self.triangles {
            if projected_area2(t) == 0.0 {
                continue;
            }
            let (lx, hx) = minmax(t[0][0], t[1][0], t[2][0]);
            let (ly, hy) = minmax(t[0][1], t[1][1], t[2][1]);
            // Widen by a hair so cell centres exactly on an edge are not lost to rounding.
            let eps = 1e-9 * res.max(1.0);
            let Some((ix0, ix1)) = index_range(lx - eps, hx + eps, x0, map.nx) else {
                continue;
            };
            let Some((iy0, iy1)) = index_range(ly - eps, hy + eps, y0, map.ny) else {
                continue;
            };
            for iy in iy0..=iy1 {
                let y = map.y_mm(iy);
                for ix in ix0..=ix1 {
                    if let Some(z) = height_in_triangle(t, map.x_mm(ix), y) {
                        let cell = &mut map.gap_mm[iy * map.nx + ix];
                        *cell = cell.min(z);
                    }
                }
            }
        }
    }
}

fn minmax(a: f64, b: f64, c: f64) -> (f64, f64) {
    (a.min(b).min(c), a.max(b).max(c))
}

/// Twice the signed area of the triangle's projection on the x/y plane.
fn projected_area2(t: &[[f64; 3]; 3]) -> f64 {
    (t[1][0] - t[0][0]) * (t[2][1] - t[0][1]) - (t[2][0] - t[0][0]) * (t[1][1] - t[0][1])
}

/// z of the triangle above `(x, y)`, if the vertical line through it crosses the triangle
/// (edges included, with a small relative tolerance so shared edges are never missed).
fn height_in_triangle(t: &[[f64; 3]; 3], x: f64, y: f64) -> Option<f64> {
    let d = projected_area2(t);
    if d == 0.0 {
        return None;
    }
    let [a, b, c] = t;
    let w0 = ((b[0] - x) * (c[1] - y) - (c[0] - x) * (b[1] - y)) / d;
    let w1 = ((c[0] - x) * (a[1] - y) - (a[0] - x) * (c[1] - y)) / d;
    let w2 = 1.0 - w0 - w1;
    const TOL: f64 = -1e-9;
    (w0 >= TOL && w1 >= TOL && w2 >= TOL).then(|| (w0 * a[2] + w1 * b[2] + w2 * c[2]).max(0.0))
}
