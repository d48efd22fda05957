//! The printed marker pattern: where each dot sits on the undeformed gel, and how much of a
//! pixel a (moved, foreshortened) dot covers.

use rig_core::optics::{MarkerConfig, MarkerPattern};

use super::noise::hash_unit;

/// A marker pattern ready for lookups.
pub(crate) struct Markers {
    pattern: MarkerPattern,
    spacing: f64,
    row_pitch: f64,
    radius: f64,
    offset: [f64; 2],
    jitter: f64,
    seed: u64,
    /// Centres of dots `i0.., j0..` precomputed (`cols` per row), so lookups skip the hashing.
    cache: Vec<[f64; 2]>,
    i0: i64,
    j0: i64,
    cols: i64,
    rows: i64,
}

impl Markers {
    /// `None` when the pattern is `none` or its numbers are unusable (validation reports those).
    pub fn new(cfg: &MarkerConfig) -> Option<Self> {
        let usable = cfg.spacing_mm.is_finite()
            && cfg.spacing_mm > 0.0
            && cfg.dot_diameter_mm.is_finite()
            && cfg.dot_diameter_mm > 0.0
            && cfg.offset_mm.iter().all(|v| v.is_finite());
        if cfg.pattern == MarkerPattern::None || !usable {
            return None;
        }
        let row_pitch = match cfg.pattern {
            MarkerPattern::Hex => cfg.spacing_mm * 3f64.sqrt() / 2.0,
            _ => cfg.spacing_mm,
        };
        let jitter = if cfg.jitter_mm.is_finite() {
            cfg.jitter_mm.clamp(0.0, cfg.spacing_mm / 2.0)
        } else {
            0.0
        };
        Some(Self {
            pattern: cfg.pattern,
            spacing: cfg.spacing_mm,
            row_pitch,
            radius: cfg.dot_diameter_mm / 2.0,
            offset: cfg.offset_mm,
            jitter,
            seed: cfg.jitter_seed,
            cache: Vec::new(),
            i0: 0,
            j0: 0,
            cols: 0,
            rows: 0,
        })
    }

    /// Precomputes the dots whose centres may be looked up for material points in
    /// `[x0, x1] × [y0, y1]` (mm); lookups elsewhere still work, computed on the fly.
    pub fn cache_region(&mut self, x0: f64, x1: f64, y0: f64, y1: f64) {
        let margin = 2.0 * self.spacing;
        let j_lo = ((y0 - self.offset[1] - margin) / self.row_pitch).floor();
        let j_hi = ((y1 - self.offset[1] + margin) / self.row_pitch).ceil();
        let i_lo = ((x0 - self.offset[0] - margin) / self.spacing).floor();
        let i_hi = ((x1 - self.offset[0] + margin) / self.spacing).ceil();
        let (cols, rows) = (i_hi - i_lo + 1.0, j_hi - j_lo + 1.0);
        if !(cols.is_finite() && rows.is_finite())
            || cols * rows > 4.0e6
            || cols < 1.0
            || rows < 1.0
        {
            return;
        }
        (self.i0, self.j0, self.cols, self.rows) =
            (i_lo as i64, j_lo as i64, cols as i64, rows as i64);
        self.cache = Vec::new();
        let mut cache = Vec::with_capacity((cols * rows) as usize);
        for j in 0..self.rows {
            for i in 0..self.cols {
                cache.push(self.centre(self.i0 + i, self.j0 + j));
            }
        }
        self.cache = cache;
    }

    fn cached_centre(&self, i: i64, j: i64) -> [f64; 2] {
        let (ci, cj) = (i - self.i0, j - self.j0);
        if (0..self.cols).contains(&ci) && (0..self.rows).contains(&cj) && !self.cache.is_empty() {
            self.cache[(cj * self.cols + ci) as usize]
        } else {
            self.centre(i, j)
        }
    }

    /// Centre of dot `(i, j)` (column, row) on the undeformed gel, mm.
    pub fn centre(&self, i: i64, j: i64) -> [f64; 2] {
        let row_shift = if self.pattern == MarkerPattern::Hex && j.rem_euclid(2) == 1 {
            self.spacing / 2.0
        } else {
            0.0
        };
        let mut c = [
            self.offset[0] + i as f64 * self.spacing + row_shift,
            self.offset[1] + j as f64 * self.row_pitch,
        ];
        if self.jitter > 0.0 {
            let key = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (j as u64).rotate_left(32);
            c[0] += self.jitter * (2.0 * hash_unit(self.seed, key, 0) - 1.0);
            c[1] += self.jitter * (2.0 * hash_unit(self.seed, key, 1) - 1.0);
        }
        c
    }

    /// Every dot centre whose undeformed position lies in `[x0, x1] × [y0, y1]`, mm.
    pub fn centres_in(&self, x0: f64, x1: f64, y0: f64, y1: f64) -> Vec<[f64; 2]> {
        let margin = self.spacing;
        let j_lo = ((y0 - self.offset[1] - margin) / self.row_pitch).floor() as i64;
        let j_hi = ((y1 - self.offset[1] + margin) / self.row_pitch).ceil() as i64;
        let i_lo = ((x0 - self.offset[0] - margin) / self.spacing).floor() as i64;
        let i_hi = ((x1 - self.offset[0] + margin) / self.spacing).ceil() as i64;
        let mut out = Vec::new();
        for j in j_lo..=j_hi {
            for i in i_lo..=i_hi {
                let c = self.centre(i, j);
                if (x0..=x1).contains(&c[0]) && (y0..=y1).contains(&c[1]) {
                    out.push(c);
                }
            }
        }
        out
    }

    /// Fraction of a pixel of size `px_mm` covered by a dot, for the material point `p` (the
    /// undeformed position of what the pixel sees). `grad` is the surface height gradient
    /// there: a dot on a slope is seen foreshortened, i.e. distances along the slope count
    /// `√(1 + (∇h·d̂)²)` times longer.
    pub fn coverage(&self, p: [f64; 2], grad: [f64; 2], px_mm: f64) -> f64 {
        let j0 = ((p[1] - self.offset[1]) / self.row_pitch).round() as i64;
        let mut best = f64::INFINITY;
        for j in j0 - 1..=j0 + 1 {
            let shift = if self.pattern == MarkerPattern::Hex && j.rem_euclid(2) == 1 {
                self.spacing / 2.0
            } else {
                0.0
            };
            let i0 = ((p[0] - self.offset[0] - shift) / self.spacing).round() as i64;
            for i in i0 - 1..=i0 + 1 {
                let c = self.cached_centre(i, j);
                let d = [p[0] - c[0], p[1] - c[1]];
                let along = grad[0] * d[0] + grad[1] * d[1];
                let dist2 = d[0] * d[0] + d[1] * d[1] + along * along;
                best = best.min(dist2);
            }
        }
        // Linear ramp one pixel wide across the dot's edge: cheap anti-aliasing.
        ((self.radius - best.sqrt()) / px_mm + 0.5).clamp(0.0, 1.0)
    }
}
