//! The printed marker pattern: where each dot sits on the undeformed gel.

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
        })
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

    /// Radius of a dot on the undeformed gel, mm.
    pub fn radius_mm(&self) -> f64 {
        self.radius
    }
}
