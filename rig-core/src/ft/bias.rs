//! Bias (tare) estimation over a window of samples.
//!
//! The sensor's offset is the mean of `n` samples taken with no load. Its uncertainty is the
//! standard error `σ / √n` per channel, reported with the estimate so an operator (and a test)
//! can tell a good tare from a hurried one. Welford's running mean/variance keeps it exact for
//! long windows. Channels are whatever the front end tares: counts-derived N/N·mm for a
//! controller, gauge volts for a DAQ.

/// Running estimator over six channels.
#[derive(Debug, Clone, Default)]
pub struct BiasEstimator {
    n: u64,
    mean: [f64; 6],
    m2: [f64; 6],
}

/// Result of a tare.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct BiasEstimate {
    /// Samples used.
    pub n: u64,
    /// Per-channel mean (the bias).
    pub mean: [f64; 6],
    /// Per-channel sample standard deviation (the noise).
    pub std: [f64; 6],
    /// Per-channel standard error of the mean, `std / √n`.
    pub std_error: [f64; 6],
}

impl BiasEstimator {
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds one sample; non-finite samples are ignored (and not counted).
    pub fn push(&mut self, x: &[f64; 6]) {
        if x.iter().any(|v| !v.is_finite()) {
            return;
        }
        self.n += 1;
        let n = self.n as f64;
        for (i, &xi) in x.iter().enumerate() {
            let d = xi - self.mean[i];
            self.mean[i] += d / n;
            self.m2[i] += d * (xi - self.mean[i]);
        }
    }

    /// Samples so far.
    pub fn count(&self) -> u64 {
        self.n
    }

    /// The estimate so far; `None` before two samples.
    pub fn estimate(&self) -> Option<BiasEstimate> {
        if self.n < 2 {
            return None;
        }
        let n = self.n as f64;
        let mut std = [0.0; 6];
        let mut se = [0.0; 6];
        for i in 0..6 {
            std[i] = (self.m2[i] / (n - 1.0)).max(0.0).sqrt();
            se[i] = std[i] / n.sqrt();
        }
        Some(BiasEstimate {
            n: self.n,
            mean: self.mean,
            std,
            std_error: se,
        })
    }
}
