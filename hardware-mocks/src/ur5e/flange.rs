//! The UR5e's own force/torque sensor at the tool flange, as RTDE `actual_TCP_force` reports
//! it: the external wrench on the tool, in the base frame, forces in N and torques in N·m about
//! the TCP.
//!
//! A real e-Series arm measures it with the sensor built into its tool flange. Its data sheet
//! (Universal Robots, "UR5e technical specifications", force/torque sensor) gives, per axis:
//! force x-y-z range 50 N, precision 3.5 N, accuracy 4.0 N; torque x-y-z range 10 N·m,
//! precision 0.2 N·m, accuracy 0.3 N·m ([`UR5E_FLANGE`]).
//!
//! The twin reads the contact physics' newest wrench (the wrench on the gel, in the sensor
//! surface frame, torques about the tip in N·mm; see `rig_sim`), turns it into the wrench on
//! the tool (the reaction: its opposite) in the base frame, and adds the sensor's error with
//! the data sheet's figures: per axis a fixed offset within ±(accuracy − precision), drawn once
//! from the seed, and noise of σ = precision / 3, clipped at ±precision, so every reading is
//! within the stated accuracy of the true wrench. It lags the contact by up to one physics
//! step (the newest one buffered), as the real sensor's filtering lags it.

use std::sync::Arc;

use nalgebra::Rotation3;

use rig_core::pose::Pose;
use rig_core::wrench::Wrench;

use crate::nano17::Rng;

/// Accuracy and precision of a flange force/torque sensor, per axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlangeSpec {
    /// Largest error of a force reading, N.
    pub force_accuracy_n: f64,
    /// Spread of repeated force readings, N.
    pub force_precision_n: f64,
    /// Largest error of a torque reading, N·m.
    pub torque_accuracy_nm: f64,
    /// Spread of repeated torque readings, N·m.
    pub torque_precision_nm: f64,
}

/// The UR5e's flange sensor, from its data sheet (see the module doc).
pub const UR5E_FLANGE: FlangeSpec = FlangeSpec {
    force_accuracy_n: 4.0,
    force_precision_n: 3.5,
    torque_accuracy_nm: 0.3,
    torque_precision_nm: 0.2,
};

/// The newest contact wrench and its clock time: on the gel, in the surface frame, torques
/// about the tip in N·mm. Must not block (it is read on every controller tick).
pub type ContactWrench = Arc<dyn Fn() -> Option<(u64, Wrench)> + Send + Sync>;

/// The twin of the flange sensor (see the module doc).
pub struct FlangeSensor {
    contact: ContactWrench,
    /// Rotation of the surface frame in the base frame (worked out once: the sensor is read on
    /// every controller tick).
    surface_rotation: Rotation3<f64>,
    spec: FlangeSpec,
    /// Fixed error per axis, N and N·m.
    offset: [f64; 6],
    rng: Rng,
}

impl std::fmt::Debug for FlangeSensor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FlangeSensor")
            .field("spec", &self.spec)
            .field("offset", &self.offset)
            .finish_non_exhaustive()
    }
}

impl FlangeSensor {
    /// A sensor reading `contact` (a press on the gel whose surface frame is `surface_frame`)
    /// with the errors of `spec`, seeded by `seed`.
    pub fn new(contact: ContactWrench, surface_frame: Pose, spec: FlangeSpec, seed: u64) -> Self {
        let mut rng = Rng::new(seed);
        let mut offset = [0.0; 6];
        for (k, o) in offset.iter_mut().enumerate() {
            let (acc, prec) = spec.axis(k);
            *o = (2.0 * rng.uniform() - 1.0) * (acc - prec).max(0.0);
        }
        Self {
            contact,
            surface_rotation: surface_frame.rotation(),
            spec,
            offset,
            rng,
        }
    }

    /// The true wrench on the tool now, base frame, N and N·m about the TCP.
    pub fn true_wrench(&self) -> [f64; 6] {
        let w = (self.contact)().map(|(_, w)| w).unwrap_or_default();
        reaction_in_base(&self.surface_rotation, &w)
    }

    /// One reading: the true wrench plus the sensor's error.
    pub fn read(&mut self) -> [f64; 6] {
        let mut out = self.true_wrench();
        for (k, v) in out.iter_mut().enumerate() {
            let (_, prec) = self.spec.axis(k);
            let noise = (self.rng.gaussian() * prec / 3.0).clamp(-prec, prec);
            *v += self.offset[k] + noise;
        }
        out
    }
}

impl FlangeSpec {
    /// (accuracy, precision) of axis `k` (0..3 forces, 3..6 torques).
    fn axis(&self, k: usize) -> (f64, f64) {
        if k < 3 {
            (self.force_accuracy_n, self.force_precision_n)
        } else {
            (self.torque_accuracy_nm, self.torque_precision_nm)
        }
    }
}

/// The wrench on the tool in the base frame (N, N·m) from the wrench `on_gel` (surface frame,
/// N and N·mm): the reaction, rotated by the surface frame's orientation.
pub fn on_tool_in_base(surface_frame: &Pose, on_gel: &Wrench) -> [f64; 6] {
    reaction_in_base(&surface_frame.rotation(), on_gel)
}

/// [`on_tool_in_base`] with the surface frame's rotation.
fn reaction_in_base(r: &Rotation3<f64>, on_gel: &Wrench) -> [f64; 6] {
    let f = r * -nalgebra::Vector3::from(on_gel.force_n);
    let t = r * -nalgebra::Vector3::from(on_gel.torque_nmm) * 1e-3;
    [f.x, f.y, f.z, t.x, t.y, t.z]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pressing(fz: f64) -> ContactWrench {
        Arc::new(move || {
            Some((
                1,
                Wrench {
                    force_n: [0.5, -0.25, fz],
                    torque_nmm: [10.0, 0.0, -20.0],
                },
            ))
        })
    }

    #[test]
    fn the_reading_is_the_reaction_in_the_base_frame_within_the_data_sheets_accuracy() {
        // A gel facing up: surface axes are the base's. Pressing on the gel (Fz < 0 on it)
        // pushes the tool up.
        let mut s = FlangeSensor::new(pressing(-12.0), Pose::default(), UR5E_FLANGE, 7);
        let truth = s.true_wrench();
        assert_eq!(truth[..3], [-0.5, 0.25, 12.0]);
        assert!((truth[3] + 0.01).abs() < 1e-12 && (truth[5] - 0.02).abs() < 1e-12);
        let n = 20_000;
        let mut sum = [0.0; 6];
        for _ in 0..n {
            let r = s.read();
            for k in 0..6 {
                let (acc, _) = UR5E_FLANGE.axis(k);
                assert!(
                    (r[k] - truth[k]).abs() <= acc,
                    "axis {k}: {} vs {}",
                    r[k],
                    truth[k]
                );
                sum[k] += r[k] - truth[k];
            }
        }
        // The mean error is the fixed offset, within its bound; the readings scatter about it.
        for (k, total) in sum.iter().enumerate() {
            let (acc, prec) = UR5E_FLANGE.axis(k);
            let mean = total / n as f64;
            assert!((mean - s.offset[k]).abs() < 0.05 * prec, "axis {k}");
            assert!(s.offset[k].abs() <= acc - prec + 1e-12);
        }
    }

    #[test]
    fn a_tilted_gel_turns_the_reaction_with_it() {
        // The gel's normal along base −x (rotated −90° about y): a press along its normal
        // pushes the tool along −x.
        let frame = Pose::new(0.4, 0.0, 0.2, 0.0, -std::f64::consts::FRAC_PI_2, 0.0);
        let w = on_tool_in_base(
            &frame,
            &Wrench {
                force_n: [0.0, 0.0, -10.0],
                torque_nmm: [0.0; 3],
            },
        );
        assert!(
            (w[0] + 10.0).abs() < 1e-9 && w[1].abs() < 1e-9 && w[2].abs() < 1e-9,
            "{w:?}"
        );
    }
}
