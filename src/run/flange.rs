//! Force safety without an F/T sensor: the UR5e's own flange sensor.
//!
//! A target sensor recorded without `[force_sensor]` (images, TCP poses and stage labels only)
//! still needs its presses watched for force. The e-Series arm measures the external wrench on
//! its tool with the force/torque sensor in its flange and reports it on every RTDE state
//! (`actual_TCP_force`: base frame, N and N·m about the TCP). The safety supervisor checks it
//! there, stop first, as it checks the Nano17's samples.
//!
//! That sensor is far coarser than a Nano17. UR's data sheet ("UR5e technical specifications",
//! force/torque sensor) gives a force accuracy of 4.0 N per axis (precision 3.5 N, range 50 N),
//! so a reading's |F| can be off by up to 4.0·√3 = 6.9 N ([`MARGIN_N`]). The supervisor
//! therefore trips when the reading's |F| passes `safety.max_force_n` less that margin: the
//! true force can then not have passed the limit. And a limit the sensor cannot tell from no
//! force at all is refused before anything connects ([`guard`]): below twice the margin, an
//! unloaded reading could already trip it.

use anyhow::bail;
use rig_core::config::{RigConfig, SensorRole};

/// The UR5e flange sensor's force accuracy per axis, N (UR5e data sheet).
pub const UR5E_FORCE_ACCURACY_N: f64 = 4.0;

/// The most a flange reading's |F| can differ from the true |F|: the per-axis accuracy on each
/// of the three axes, N.
pub const MARGIN_N: f64 = UR5E_FORCE_ACCURACY_N * 1.732_050_807_568_877_2;

/// The force check on the flange sensor's readings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlangeGuard {
    /// `safety.max_force_n`, N.
    pub limit_n: f64,
    /// A reading's |F| above this trips: the limit less [`MARGIN_N`], N.
    pub threshold_n: f64,
}

impl FlangeGuard {
    /// |F| of a reading `[Fx, Fy, Fz, …]`, N (NaN when not finite).
    pub fn force_n(reading: &[f64; 6]) -> f64 {
        let f = &reading[..3];
        let n = (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt();
        if n.is_finite() { n } else { f64::NAN }
    }

    /// Whether a reading trips the guard (a non-finite reading does: nothing is known).
    pub fn trips(&self, reading: &[f64; 6]) -> bool {
        let n = Self::force_n(reading);
        n.is_nan() || n > self.threshold_n
    }
}

/// The flange guard a run needs: `None` with an F/T sensor (its samples are checked), else the
/// guard on the UR5e's flange sensor. Refuses a source sensor without an F/T sensor (its
/// recording is the force labels) and a force limit the flange sensor cannot enforce.
pub fn guard(config: &RigConfig) -> anyhow::Result<Option<FlangeGuard>> {
    if config.force_sensor.is_some() {
        return Ok(None);
    }
    if config.sensor.role == SensorRole::Source {
        bail!(
            "sensor {} is a source sensor but the config has no [force_sensor]: a source \
             recording is the force labels. Add the section (see rig-configs/lab-example.toml), \
             or set sensor.role = \"target\" to record images, poses and stages only",
            config.sensor.id
        );
    }
    let limit_n = config.safety.max_force_n;
    let floor = 2.0 * MARGIN_N;
    if limit_n < floor {
        bail!(
            "with no [force_sensor], the force limit is enforced with the UR5e's flange sensor, \
             whose readings are within {UR5E_FORCE_ACCURACY_N} N per axis (UR5e data sheet), \
             {MARGIN_N:.1} N on |F|; safety.max_force_n = {limit_n} N is within that of no \
             force at all. Raise it to at least {floor:.1} N, or fit an F/T sensor \
             ([force_sensor]) for a finer limit"
        );
    }
    Ok(Some(FlangeGuard {
        limit_n,
        threshold_n: limit_n - MARGIN_N,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config(role: &str, max_force_n: f64) -> RigConfig {
        let mut c = RigConfig::sim_target();
        c.sensor.role = if role == "source" {
            SensorRole::Source
        } else {
            SensorRole::Target
        };
        c.safety.max_force_n = max_force_n;
        c.force_sensor = None;
        c
    }

    #[test]
    fn the_threshold_is_the_limit_less_the_sensors_accuracy_on_f() {
        let g = guard(&config("target", 20.0)).unwrap().unwrap();
        assert!((g.threshold_n - (20.0 - 4.0 * 3f64.sqrt())).abs() < 1e-9);
        assert!(!g.trips(&[0.0, 0.0, 13.0, 0.0, 0.0, 0.0]));
        assert!(g.trips(&[0.0, 8.0, 11.0, 0.0, 0.0, 0.0]), "|F| 13.6 N");
        assert!(g.trips(&[f64::NAN, 0.0, 0.0, 0.0, 0.0, 0.0]));
        // With an F/T sensor its samples are checked instead.
        assert_eq!(guard(&RigConfig::sim_target()).unwrap(), None);
    }

    #[test]
    fn a_source_without_an_ft_sensor_and_a_limit_below_the_sensors_reach_are_refused() {
        let e = guard(&config("source", 20.0)).unwrap_err().to_string();
        assert!(
            e.contains("source sensor") && e.contains("[force_sensor]"),
            "{e}"
        );
        let e = guard(&config("target", 10.0)).unwrap_err().to_string();
        assert!(
            e.contains("max_force_n = 10 N") && e.contains("at least 13.9 N"),
            "{e}"
        );
    }
}
