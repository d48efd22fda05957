//! Force/torque values.
//!
//! Units are fixed project-wide: forces in newtons, torques in newton-millimetres (ATI quotes
//! Nano17 torque ranges in N·mm). The frame a wrench is expressed in is always stated where one
//! is produced.

use serde::{Deserialize, Serialize};

/// A wrench `[Fx, Fy, Fz]` (N) and `[Tx, Ty, Tz]` (N·mm).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Wrench {
    pub force_n: [f64; 3],
    pub torque_nmm: [f64; 3],
}

impl Wrench {
    pub const ZERO: Wrench = Wrench {
        force_n: [0.0; 3],
        torque_nmm: [0.0; 3],
    };

    /// From `[Fx, Fy, Fz, Tx, Ty, Tz]` (N, N·mm).
    pub const fn from_array(a: [f64; 6]) -> Self {
        Self {
            force_n: [a[0], a[1], a[2]],
            torque_nmm: [a[3], a[4], a[5]],
        }
    }

    /// `[Fx, Fy, Fz, Tx, Ty, Tz]` (N, N·mm).
    pub const fn to_array(&self) -> [f64; 6] {
        let (f, t) = (self.force_n, self.torque_nmm);
        [f[0], f[1], f[2], t[0], t[1], t[2]]
    }

    /// Whether every component is finite.
    pub fn is_finite(&self) -> bool {
        self.to_array().iter().all(|v| v.is_finite())
    }
}
