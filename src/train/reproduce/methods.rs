//! The methods `rig reproduce` trains and compares, and the paper's reported results they are
//! judged against.

use crate::train::demo::METHOD_MARKER_FLOW;

/// One method of the protocol.
#[derive(Debug, Clone, Copy)]
pub struct Method {
    pub name: &'static str,
    /// Trained on the translated images (else on the source sensor's own).
    pub translated: bool,
    pub lstm: bool,
    /// Reads the marker-displacement modalities (D, D+S) instead of the paper's (R, M, R+M).
    pub markers: bool,
}

/// The methods, in the report's order: the paper's three (source-only with the LSTM,
/// TransForce without and with it), then ours, which reads the markers' displacement instead
/// of a translated image (`--modality flow`; with and without the LSTM, so that the paper's
/// LSTM claim can be judged where shear crosses).
pub const METHODS: [Method; 5] = [
    Method {
        name: "source-only",
        translated: false,
        lstm: true,
        markers: false,
    },
    Method {
        name: "TransForce (no LSTM)",
        translated: true,
        lstm: false,
        markers: false,
    },
    Method {
        name: "TransForce",
        translated: true,
        lstm: true,
        markers: false,
    },
    Method {
        name: "marker flow (no LSTM)",
        translated: false,
        lstm: false,
        markers: true,
    },
    Method {
        name: METHOD_MARKER_FLOW,
        translated: false,
        lstm: true,
        markers: true,
    },
];

/// The paper's reported results on its real sensors (seen group, LSTM): MAE Fx and Fy with
/// the marker modality, Fz with R+M (N), their work range (N: Fx, Fy ±6, Fz −16..0), the best
/// R² per axis, and FID before (I_s–I_t) and after (Î_t–I_t) translation, seen and unseen.
pub const PAPER_MAE_N: [f64; 3] = [0.695, 0.701, 1.112];
pub const PAPER_RANGE_N: [f64; 3] = [12.0, 12.0, 16.0];
pub const PAPER_R2: [f64; 3] = [0.69, 0.66, 0.79];
pub const PAPER_FID_BEFORE: [f64; 2] = [81.1, 87.9];
pub const PAPER_FID_AFTER: [f64; 2] = [18.3, 21.3];
