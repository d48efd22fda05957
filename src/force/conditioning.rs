//! Per-sample conditioning, sans I/O: how raw readings (counts or gauge volts) become a
//! sensor-frame wrench ([`RawMap`]), the tare, the tool transform to the indenter tip, and the
//! saturation and status checks ([`Conditioner`]); and [`FrontEndSettings`], everything a front
//! end needs besides its port, resolved from a `[force_sensor]` section.

use rig_core::config::{ForceSensorConfig, ForceSensorKind, SaturationPolicy};
use rig_core::ft::bias::{BiasEstimate, BiasEstimator};
use rig_core::ft::cal::Calibration;
use rig_core::ft::transform::ToolTransform;
use rig_core::ft::{NANO17_SI_25_MAX, SampleFlags};
use tokio::sync::oneshot;

use super::error::FtError;

/// Result of a tare.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct TareReport {
    /// The bias in the front end's raw units (N and N·mm for counts; volts for DAQ gauges).
    pub raw: BiasEstimate,
    /// The bias and noise as a wrench (sensor frame, N and N·mm).
    pub wrench: BiasEstimate,
}

/// How raw readings become a sensor-frame wrench.
#[derive(Debug, Clone)]
pub enum RawMap {
    /// Counts from a controller or Net F/T: N = counts / cpf, N·mm = counts / cpt.
    Counts {
        counts_per_force: f64,
        counts_per_torque: f64,
    },
    /// Gauge volts: `F = M · (V' − bias)`, `V'` temperature-compensated when enabled.
    Gauges {
        calibration: Box<Calibration>,
        temperature_compensation: bool,
    },
}

/// One sample after conditioning.
#[derive(Debug, Clone, Copy)]
pub struct Conditioned {
    pub wrench: [f64; 6],
    pub flags: SampleFlags,
    /// The sample should be delivered (false: dropped by the saturation policy).
    pub keep: bool,
    /// The policy says stop.
    pub stop: bool,
}

struct PendingTare {
    target: u64,
    raw: BiasEstimator,
    wrench: BiasEstimator,
    reply: oneshot::Sender<TareReport>,
}

/// Per-sample conditioning, sans I/O: tare, tool transform, saturation and status checks.
pub struct Conditioner {
    map: RawMap,
    tool: ToolTransform,
    max_loads: [f64; 6],
    policy: SaturationPolicy,
    bias: Option<[f64; 6]>,
    tare: Option<PendingTare>,
}

impl Conditioner {
    pub fn new(
        map: RawMap,
        tool: ToolTransform,
        max_loads: [f64; 6],
        policy: SaturationPolicy,
    ) -> Self {
        Self {
            map,
            tool,
            max_loads,
            policy,
            bias: None,
            tare: None,
        }
    }

    /// Sets the bias directly (raw units).
    pub fn set_bias(&mut self, bias: [f64; 6]) {
        self.bias = Some(bias);
    }

    /// The current bias (raw units), if tared.
    pub fn bias(&self) -> Option<[f64; 6]> {
        self.bias
    }

    /// Starts a tare over the next `n` samples; the report is sent on `reply`.
    pub fn start_tare(&mut self, n: u64, reply: oneshot::Sender<TareReport>) {
        self.tare = Some(PendingTare {
            target: n.max(2),
            raw: BiasEstimator::new(),
            wrench: BiasEstimator::new(),
            reply,
        });
    }

    fn to_sensor(&self, raw: &[f64; 6], bias: &[f64; 6]) -> [f64; 6] {
        match &self.map {
            RawMap::Counts {
                counts_per_force,
                counts_per_torque,
            } => {
                let tared: [f64; 6] = std::array::from_fn(|i| raw[i] - bias[i]);
                rig_core::ft::counts_to_wrench(&tared, *counts_per_force, *counts_per_torque)
            }
            RawMap::Gauges { calibration, .. } => calibration.wrench(raw, bias),
        }
    }

    /// Conditions one reading. `raw`: counts (as f64) or gauge volts; `thermistor_v` for DAQ;
    /// `status`: the device's status word; `flags`: what the reader already knows (gaps,
    /// reordering, gauge saturation).
    pub fn process(
        &mut self,
        raw: &[f64; 6],
        thermistor_v: Option<f64>,
        status: u32,
        mut flags: SampleFlags,
    ) -> Conditioned {
        let raw = match &self.map {
            RawMap::Gauges {
                calibration,
                temperature_compensation: true,
            } if calibration.temperature.is_some() => {
                let (g, ok) = calibration.compensate(raw, thermistor_v);
                if !ok || thermistor_v.is_none() {
                    flags |= SampleFlags::TEMPERATURE_UNCOMPENSATED;
                }
                g
            }
            _ => *raw,
        };
        if let Some(t) = self.tare.as_mut() {
            t.raw.push(&raw);
            let w = self.to_sensor(&raw, &[0.0; 6]);
            if let Some(t) = self.tare.as_mut() {
                t.wrench.push(&w);
            }
        }
        if self
            .tare
            .as_ref()
            .is_some_and(|t| t.raw.count() >= t.target)
            && let Some(t) = self.tare.take()
            && let Some(est) = t.raw.estimate()
        {
            self.bias = Some(est.mean);
            let _ = t.reply.send(TareReport {
                raw: est,
                wrench: self.wrench_estimate(&est, &t.wrench),
            });
        }
        let zero = [0.0; 6];
        let bias = self.bias.as_ref().unwrap_or(&zero);
        if self.bias.is_none() {
            flags |= SampleFlags::UNTARED;
        }
        let sensor = self.to_sensor(&raw, bias);
        let mask = rig_core::ft::saturation_mask(&sensor, &self.max_loads);
        if mask != 0 {
            flags.set_saturated_axes(mask);
        }
        if status != 0 {
            flags |= SampleFlags::DEVICE_STATUS;
        }
        let saturated =
            flags.contains(SampleFlags::SATURATED) || flags.contains(SampleFlags::GAUGE_SATURATED);
        let (keep, stop) = match (saturated, self.policy) {
            (false, _) | (true, SaturationPolicy::Flag) => (true, false),
            (true, SaturationPolicy::Drop) => (false, false),
            (true, SaturationPolicy::Stop) => (false, true),
        };
        Conditioned {
            wrench: self.tool.apply(&sensor),
            flags,
            keep,
            stop,
        }
    }

    fn wrench_estimate(&self, raw: &BiasEstimate, wrench: &BiasEstimator) -> BiasEstimate {
        let mean = self.to_sensor(&raw.mean, &[0.0; 6]);
        match wrench.estimate() {
            Some(mut w) => {
                w.mean = mean;
                w.n = raw.n;
                let n = raw.n as f64;
                w.std_error = w.std.map(|s| s / n.sqrt());
                w
            }
            None => BiasEstimate {
                n: raw.n,
                mean,
                std: [0.0; 6],
                std_error: [0.0; 6],
            },
        }
    }
}

/// Everything a front end needs besides its port, resolved from a `[force_sensor]` section.
#[derive(Debug, Clone)]
pub struct FrontEndSettings {
    pub tool: ToolTransform,
    pub max_loads: [f64; 6],
    pub saturation: SaturationPolicy,
    pub calibration: Option<Calibration>,
    pub temperature_compensation: bool,
    pub counts_per_force: f64,
    pub counts_per_torque: f64,
    pub rate_hz: f64,
}

impl FrontEndSettings {
    /// Loads the calibration file (if any) and checks the tool transform.
    pub fn from_config(cfg: &ForceSensorConfig) -> Result<Self, FtError> {
        let tool = ToolTransform::from_angles(
            cfg.tool_offset_mm,
            cfg.tool_rotation_deg.map(f64::to_radians),
        )?;
        let calibration = match &cfg.calibration_file {
            Some(p) => Some(Calibration::load(p)?),
            None => None,
        };
        let max_loads = cfg
            .max_loads
            .or(calibration.as_ref().map(|c| c.max_loads))
            .unwrap_or(NANO17_SI_25_MAX);
        let (dcpf, dcpt) = match cfg.kind {
            ForceSensorKind::Netft | ForceSensorKind::Sim => (
                rig_core::ft::netft::FACTORY_COUNTS_PER_FORCE,
                rig_core::ft::netft::FACTORY_COUNTS_PER_TORQUE,
            ),
            _ => (
                rig_core::ft::serial::DEFAULT_COUNTS_PER_FORCE,
                rig_core::ft::serial::DEFAULT_COUNTS_PER_TORQUE,
            ),
        };
        Ok(Self {
            tool,
            max_loads,
            saturation: cfg.saturation,
            calibration,
            temperature_compensation: cfg.temperature_compensation,
            counts_per_force: cfg.counts_per_force.unwrap_or(dcpf),
            counts_per_torque: cfg.counts_per_torque.unwrap_or(dcpt),
            rate_hz: cfg.rate_hz,
        })
    }

    /// A conditioner for gauge volts, the one code path of both DAQ routes (NI-DAQmx and the
    /// serial framing): the calibration file, with its temperature compensation when enabled.
    /// `kind` names the config value in the error when no calibration file is set.
    pub fn gauges_conditioner(&self, kind: &str) -> Result<Conditioner, FtError> {
        let calibration = self.calibration.clone().ok_or_else(|| {
            FtError::Config(format!(
                "force_sensor.calibration_file is required when force_sensor.kind is \"{kind}\""
            ))
        })?;
        Ok(Conditioner::new(
            RawMap::Gauges {
                calibration: Box::new(calibration),
                temperature_compensation: self.temperature_compensation,
            },
            self.tool.clone(),
            self.max_loads,
            self.saturation,
        ))
    }

    /// Whether a gauge route reads the thermistor: compensation is on and the calibration file
    /// has its data.
    pub fn reads_thermistor(&self) -> bool {
        self.temperature_compensation
            && self
                .calibration
                .as_ref()
                .is_some_and(|c| c.temperature.is_some())
    }

    /// A conditioner for counts.
    pub fn counts_conditioner(&self) -> Conditioner {
        Conditioner::new(
            RawMap::Counts {
                counts_per_force: self.counts_per_force,
                counts_per_torque: self.counts_per_torque,
            },
            self.tool.clone(),
            self.max_loads,
            self.saturation,
        )
    }
}
