//! Wrench at a frame's time: nearest sample, linear, or cubic interpolation, with the sync error.
//!
//! The input is a stream of wrench samples already on the host clock, sorted by time. The result
//! always says how far the frame time was from the nearest real sample ([`Interpolated::
//! sync_error_ns`]) and whether it fell inside the stream. Nothing is extrapolated: a frame time
//! before the first or after the last sample gets the nearest sample's value only within
//! `max_extrapolation_ns` (flagged `inside = false`), and is refused beyond it; a frame that falls
//! in a hole of the stream wider than `max_gap_ns` is refused too ([`InterpError`]).
//!
//! Cubic is the cubic Hermite spline with Catmull-Rom tangents generalised to non-uniform
//! spacing (`m_k = (p_{k+1} − p_{k−1}) / (t_{k+1} − t_{k−1})`; one-sided at the stream's ends).
//! It passes through the samples, is C¹, and needs one sample on either side of the bracketing
//! pair.

use rig_core::wrench::Wrench;
use serde::{Deserialize, Serialize};

/// How the wrench is evaluated between samples.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum InterpMethod {
    Nearest,
    Linear,
    Cubic,
}

impl InterpMethod {
    /// Samples needed after the frame time before the value is final.
    pub fn samples_after(self) -> usize {
        match self {
            InterpMethod::Nearest | InterpMethod::Linear => 1,
            InterpMethod::Cubic => 2,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            InterpMethod::Nearest => "nearest",
            InterpMethod::Linear => "linear",
            InterpMethod::Cubic => "cubic",
        }
    }
}

/// One wrench sample on the host clock.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TimedWrench {
    /// Host time, ns (fractional: it comes from a clock map).
    pub t_ns: f64,
    pub wrench: Wrench,
}

/// Bounds on what the interpolator accepts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InterpLimits {
    /// A bracketing pair of samples further apart than this is a gap in the stream.
    pub max_gap_ns: f64,
    /// Hold the first/last sample this far beyond the stream's ends (flagged), refuse beyond.
    pub max_extrapolation_ns: f64,
}

impl Default for InterpLimits {
    fn default() -> Self {
        // At 1 kHz a 5 ms gap is 4 lost samples; half a sample period outside is rounding.
        Self {
            max_gap_ns: 5e6,
            max_extrapolation_ns: 0.5e6,
        }
    }
}

/// The wrench at a time, and how trustworthy it is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Interpolated {
    pub wrench: Wrench,
    /// Distance in time to the nearest real sample, ns.
    pub sync_error_ns: f64,
    /// Whether the time lay between the first and the last sample.
    pub inside: bool,
}

/// Why no wrench was produced for a time.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum InterpError {
    #[error("no wrench samples")]
    Empty,
    #[error("frame time is {by_ns:.0} ns outside the wrench stream (limit exceeded)")]
    OutOfRange { by_ns: f64 },
    #[error("frame time falls in a {gap_ns:.0} ns gap of the wrench stream")]
    Gap { gap_ns: f64 },
    #[error("frame time is not finite")]
    BadTime,
}

/// Evaluate `samples` (sorted by `t_ns`) at `t_ns`.
pub fn interpolate(
    samples: &[TimedWrench],
    t_ns: f64,
    method: InterpMethod,
    limits: &InterpLimits,
) -> Result<Interpolated, InterpError> {
    if !t_ns.is_finite() {
        return Err(InterpError::BadTime);
    }
    let (Some(first), Some(last)) = (samples.first(), samples.last()) else {
        return Err(InterpError::Empty);
    };
    if t_ns < first.t_ns || t_ns > last.t_ns {
        let s = if t_ns < first.t_ns { first } else { last };
        let by = (t_ns - s.t_ns).abs();
        if by > limits.max_extrapolation_ns {
            return Err(InterpError::OutOfRange { by_ns: by });
        }
        return Ok(Interpolated {
            wrench: s.wrench,
            sync_error_ns: by,
            inside: false,
        });
    }
    // Index of the first sample at or after t; t lies in [samples[i-1], samples[i]].
    let i = samples.partition_point(|s| s.t_ns < t_ns);
    if samples[i].t_ns == t_ns || i == 0 {
        return Ok(Interpolated {
            wrench: samples[i].wrench,
            sync_error_ns: 0.0,
            inside: true,
        });
    }
    let (a, b) = (&samples[i - 1], &samples[i]);
    let gap = b.t_ns - a.t_ns;
    let sync_error_ns = (t_ns - a.t_ns).min(b.t_ns - t_ns);
    if gap > limits.max_gap_ns {
        return Err(InterpError::Gap { gap_ns: gap });
    }
    let s = (t_ns - a.t_ns) / gap;
    let wrench = match method {
        InterpMethod::Nearest => {
            if s <= 0.5 {
                a.wrench
            } else {
                b.wrench
            }
        }
        InterpMethod::Linear => lerp(&a.wrench, &b.wrench, s),
        InterpMethod::Cubic => {
            let before = (i >= 2).then(|| &samples[i - 2]);
            let after = samples.get(i + 1);
            hermite(before, a, b, after, t_ns)
        }
    };
    Ok(Interpolated {
        wrench,
        sync_error_ns,
        inside: true,
    })
}

fn lerp(a: &Wrench, b: &Wrench, s: f64) -> Wrench {
    let (a, b) = (a.to_array(), b.to_array());
    Wrench::from_array(std::array::from_fn(|k| a[k] + (b[k] - a[k]) * s))
}

fn hermite(
    before: Option<&TimedWrench>,
    a: &TimedWrench,
    b: &TimedWrench,
    after: Option<&TimedWrench>,
    t_ns: f64,
) -> Wrench {
    let h = b.t_ns - a.t_ns;
    let (pa, pb) = (a.wrench.to_array(), b.wrench.to_array());
    let slope = |p: &TimedWrench, q: &TimedWrench, k: usize| {
        (q.wrench.to_array()[k] - p.wrench.to_array()[k]) / (q.t_ns - p.t_ns)
    };
    let s = (t_ns - a.t_ns) / h;
    let (s2, s3) = (s * s, s * s * s);
    let h00 = 2.0 * s3 - 3.0 * s2 + 1.0;
    let h10 = s3 - 2.0 * s2 + s;
    let h01 = -2.0 * s3 + 3.0 * s2;
    let h11 = s3 - s2;
    Wrench::from_array(std::array::from_fn(|k| {
        let ma = match before {
            Some(p) => slope(p, b, k),
            None => slope(a, b, k),
        };
        let mb = match after {
            Some(q) => slope(a, q, k),
            None => slope(a, b, k),
        };
        h00 * pa[k] + h10 * h * ma + h01 * pb[k] + h11 * h * mb
    }))
}

/// A frame's capture time on the host clock from its stamp: the stamp mapped to host time minus
/// the configured exposure latency (the time from the middle of the exposure to the stamp; for
/// uvcvideo's start-of-frame stamps, roughly half the exposure plus the sensor readout before it).
pub fn mid_exposure_ns(stamp_host_ns: f64, exposure_latency_ns: f64) -> f64 {
    stamp_host_ns - exposure_latency_ns
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stream(f: impl Fn(f64) -> f64, t: &[f64]) -> Vec<TimedWrench> {
        t.iter()
            .map(|&t| TimedWrench {
                t_ns: t,
                wrench: Wrench::from_array([f(t), 0.0, 0.0, 0.0, 0.0, 0.0]),
            })
            .collect()
    }

    #[test]
    fn methods_on_a_line_and_a_cubic() {
        let lim = InterpLimits {
            max_gap_ns: 10.0,
            max_extrapolation_ns: 1.0,
        };
        let ts = [0.0, 2.0, 4.0, 6.0, 8.0];
        let line = stream(|t| 3.0 * t + 1.0, &ts);
        let l = interpolate(&line, 3.0, InterpMethod::Linear, &lim).unwrap();
        assert_eq!(l.wrench.force_n[0], 10.0);
        assert_eq!(l.sync_error_ns, 1.0);
        let c = interpolate(&line, 3.0, InterpMethod::Cubic, &lim).unwrap();
        assert!((c.wrench.force_n[0] - 10.0).abs() < 1e-12);
        let n = interpolate(&line, 3.5, InterpMethod::Nearest, &lim).unwrap();
        assert_eq!(n.wrench.force_n[0], 13.0);
        // Catmull-Rom reproduces quadratics on a uniform grid in the interior.
        let quad = stream(|t| t * t, &ts);
        let c = interpolate(&quad, 3.0, InterpMethod::Cubic, &lim).unwrap();
        assert!((c.wrench.force_n[0] - 9.0).abs() < 0.3, "{c:?}");
        let l = interpolate(&quad, 3.0, InterpMethod::Linear, &lim).unwrap();
        assert_eq!(l.wrench.force_n[0], 10.0);
    }

    #[test]
    fn outside_and_gaps_are_flagged_or_refused() {
        let lim = InterpLimits {
            max_gap_ns: 3.0,
            max_extrapolation_ns: 1.0,
        };
        let s = stream(|t| t, &[0.0, 2.0, 10.0, 12.0]);
        let held = interpolate(&s, 12.5, InterpMethod::Linear, &lim).unwrap();
        assert!(!held.inside);
        assert_eq!(held.wrench.force_n[0], 12.0);
        assert_eq!(held.sync_error_ns, 0.5);
        assert_eq!(
            interpolate(&s, 14.0, InterpMethod::Linear, &lim),
            Err(InterpError::OutOfRange { by_ns: 2.0 })
        );
        assert_eq!(
            interpolate(&s, 5.0, InterpMethod::Cubic, &lim),
            Err(InterpError::Gap { gap_ns: 8.0 })
        );
        assert_eq!(
            interpolate(&[], 1.0, InterpMethod::Nearest, &lim),
            Err(InterpError::Empty)
        );
        assert_eq!(
            interpolate(&s, f64::NAN, InterpMethod::Nearest, &lim),
            Err(InterpError::BadTime)
        );
    }
}
