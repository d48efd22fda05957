//! ATI Nano17 force/torque sensing, without I/O.
//!
//! A lab reads its Nano17 in one of four ways, and each has a sans-IO core here; the rig's
//! `force` module owns the ports and sockets and feeds these cores bytes and times.
//!
//! - [`serial`]: an ATI F/T controller over RS-232. Commands are ASCII lines ended by CR
//!   (`CD A`, `CD B`, `CD R`, `QR`, `QS`, `SB`, `SA n`); records are either ASCII lines
//!   (status, then six counts, CRLF) or 13-byte binary records (status byte + six big-endian
//!   `i16`). The controller applies the sensor's calibration itself: newtons are counts / CPF,
//!   N·mm counts / CPT.
//! - [`netft`]: an ATI Net F/T box over UDP port 49152 (RDT): an 8-byte request starts or
//!   stops streaming, every 36-byte record carries a `u32` RDT sequence from which
//!   [`sequence::SequenceTracker`] counts lost, reordered and duplicated packets exactly.
//! - [`nidaqmx`]: ATI's DAQ F/T system, the gauge voltages (and a thermistor) on an NI
//!   data-acquisition card read through NI-DAQmx: the C API's constants and error codes and
//!   NI's physical-channel syntax. The rig applies the sensor's calibration file.
//! - [`daq`]: raw gauge voltages (and a thermistor) from a home-built front end over a serial
//!   link, in this project's own framing with a CRC-16 (spec in that module), for a lab without
//!   an NI card. The rig turns them into a wrench with the calibration file, as for NI.
//!
//! Shared pieces:
//!
//! - [`cal`]: the ATI `.cal` calibration file: the 6×6 matrix (N and N·mm per gauge volt), max
//!   loads, optional temperature compensation, unit conversion, conditioning checks.
//! - [`transform`]: the tool transform that moves a wrench from the sensor's reference point to
//!   the indenter tip, with a near-singularity check.
//! - [`bias`]: the tare estimator (mean and standard error over a window of samples).
//! - [`sequence`]: a device's u32 sequence number (RDT, DAQ frames): loss, reordering and
//!   duplicate counts, and the number unwrapped to a u64.
//! - [`SampleFlags`] and [`saturation_mask`]: what is wrong with one sample, never passed
//!   silently.
//!
//! - The Nano17 SI-25-0.25's data-sheet values ([`NANO17_SI_25_MAX`],
//!   [`NANO17_SI_25_RESOLUTION`]), the counts per unit of each front end
//!   ([`serial::DEFAULT_COUNTS_PER_FORCE`], [`netft::FACTORY_COUNTS_PER_FORCE`], ...) and the
//!   one conversion between counts and N, N·mm ([`counts_to_wrench`], [`wrench_to_counts`]):
//!   named here once, used by the rig's readers and the simulated devices alike.
//!
//! Units: forces in N, torques in N·mm, gauge signals in volts, time in `t_ns`.

pub mod bias;
pub mod cal;
pub mod daq;
pub mod netft;
pub mod nidaqmx;
pub mod sequence;
pub mod serial;
pub mod transform;

use std::fmt;

/// Axis names in the order used everywhere: `[Fx, Fy, Fz, Tx, Ty, Tz]`.
pub const AXES: [&str; 6] = ["Fx", "Fy", "Fz", "Tx", "Ty", "Tz"];

/// Sample rate a front end is asked for when `force_sensor.rate_hz` is not given, Hz; the
/// simulated F/T controller and DAQ front end stream at it by default.
pub const DEFAULT_RATE_HZ: f64 = 1000.0;

/// Nano17 SI-25-0.25 ranges (ATI Nano17 data sheet): Fx, Fy ±25 N, Fz ±35 N, Tx..Tz ±250 N·mm.
pub const NANO17_SI_25_MAX: [f64; 6] = [25.0, 25.0, 35.0, 250.0, 250.0, 250.0];
/// Nano17 SI-25-0.25 resolution (ATI data sheet): 1/160 N for forces, 1/32 N·mm for Tx, Ty and
/// 1/64 N·mm for Tz (with an F/T controller or a 16-bit DAQ).
pub const NANO17_SI_25_RESOLUTION: [f64; 6] = [
    1.0 / 160.0,
    1.0 / 160.0,
    1.0 / 160.0,
    1.0 / 32.0,
    1.0 / 32.0,
    1.0 / 64.0,
];

/// What is wrong with one wrench sample. Flags are bits; several may be set.
#[derive(Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct SampleFlags(pub u16);

impl SampleFlags {
    pub const NONE: Self = Self(0);
    /// At least one axis is at or beyond its max load (see [`saturation_mask`]); which axes is
    /// in [`Self::saturated_axes`].
    pub const SATURATED: Self = Self(1 << 0);
    /// At least one raw gauge is at or beyond the front end's input range (DAQ).
    pub const GAUGE_SATURATED: Self = Self(1 << 1);
    /// The device reported a non-zero status / error word.
    pub const DEVICE_STATUS: Self = Self(1 << 2);
    /// Temperature compensation was asked for but the thermistor reading is unusable.
    pub const TEMPERATURE_UNCOMPENSATED: Self = Self(1 << 3);
    /// The sample follows a gap in the device's sequence (lost records before it).
    pub const AFTER_GAP: Self = Self(1 << 4);
    /// The sample arrived after a later one (UDP reordering).
    pub const REORDERED: Self = Self(1 << 5);
    /// The stream is not tared yet (bias unknown): the wrench includes the sensor's offset.
    pub const UNTARED: Self = Self(1 << 6);

    const AXES_SHIFT: u16 = 8;

    pub const fn contains(self, other: Self) -> bool {
        self.0 & other.0 == other.0
    }
    pub const fn union(self, other: Self) -> Self {
        Self(self.0 | other.0)
    }
    pub fn insert(&mut self, other: Self) {
        self.0 |= other.0;
    }
    pub const fn is_clean(self) -> bool {
        self.0 == 0
    }
    /// Record which axes saturated (bit i = axis i of [`AXES`]) and set [`Self::SATURATED`].
    pub fn set_saturated_axes(&mut self, mask: u8) {
        let mask = u16::from(mask & 0x3f);
        self.0 = (self.0 & !(0x3f << Self::AXES_SHIFT)) | (mask << Self::AXES_SHIFT);
        if mask != 0 {
            self.0 |= Self::SATURATED.0;
        }
    }
    /// Bit i set: axis i of [`AXES`] is at or beyond its max load.
    pub const fn saturated_axes(self) -> u8 {
        ((self.0 >> Self::AXES_SHIFT) & 0x3f) as u8
    }
}

impl std::ops::BitOr for SampleFlags {
    type Output = Self;
    fn bitor(self, rhs: Self) -> Self {
        self.union(rhs)
    }
}

impl std::ops::BitOrAssign for SampleFlags {
    fn bitor_assign(&mut self, rhs: Self) {
        self.insert(rhs);
    }
}

impl fmt::Debug for SampleFlags {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "SampleFlags({self})")
    }
}

impl fmt::Display for SampleFlags {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.is_clean() {
            return f.write_str("ok");
        }
        let mut parts: Vec<String> = Vec::new();
        if self.contains(Self::SATURATED) {
            let axes: Vec<&str> = (0..6)
                .filter(|i| self.saturated_axes() & (1 << i) != 0)
                .map(|i| AXES[i])
                .collect();
            parts.push(format!("saturated({})", axes.join(",")));
        }
        for (flag, name) in [
            (Self::GAUGE_SATURATED, "gauge-saturated"),
            (Self::DEVICE_STATUS, "device-status"),
            (Self::TEMPERATURE_UNCOMPENSATED, "temperature-uncompensated"),
            (Self::AFTER_GAP, "after-gap"),
            (Self::REORDERED, "reordered"),
            (Self::UNTARED, "untared"),
        ] {
            if self.contains(flag) {
                parts.push(name.to_owned());
            }
        }
        f.write_str(&parts.join(" "))
    }
}

/// Bit i set when `|values[i]| >= max[i]` (or the value is not finite). An axis whose max is not
/// a positive number is never flagged.
pub fn saturation_mask(values: &[f64; 6], max: &[f64; 6]) -> u8 {
    let mut mask = 0u8;
    for i in 0..6 {
        let v = values[i];
        if max[i] > 0.0 && (!v.is_finite() || v.abs() >= max[i]) {
            mask |= 1 << i;
        }
    }
    mask
}

/// Counts per unit of axis `axis` of `[Fx, Fy, Fz, Tx, Ty, Tz]`: counts per force (per N) for
/// the forces, counts per torque (per N·mm) for the torques.
pub fn counts_per_unit(axis: usize, counts_per_force: f64, counts_per_torque: f64) -> f64 {
    if axis < 3 {
        counts_per_force
    } else {
        counts_per_torque
    }
}

/// F/T counts to `[Fx, Fy, Fz]` N and `[Tx, Ty, Tz]` N·mm: forces divide by counts per force,
/// torques by counts per torque (ATI: newtons = counts / CPF, N·mm = counts / CPT). The counts
/// are `f64` so that a tare (a mean of counts) can be subtracted first.
pub fn counts_to_wrench(
    counts: &[f64; 6],
    counts_per_force: f64,
    counts_per_torque: f64,
) -> [f64; 6] {
    std::array::from_fn(|i| counts[i] / counts_per_unit(i, counts_per_force, counts_per_torque))
}

/// The inverse of [`counts_to_wrench`]: what a controller or Net F/T sends for a wrench, each
/// axis rounded to whole counts and clamped to the `i32` range.
pub fn wrench_to_counts(
    wrench: &[f64; 6],
    counts_per_force: f64,
    counts_per_torque: f64,
) -> [i32; 6] {
    std::array::from_fn(|i| {
        (wrench[i] * counts_per_unit(i, counts_per_force, counts_per_torque))
            .round()
            .clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32
    })
}

/// Big-endian `u32` at byte `at` of `b` (DAQ frames and RDT records are big-endian).
pub(crate) fn be_u32(b: &[u8], at: usize) -> u32 {
    u32::from_be_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

/// Six big-endian `i32` (gauges or counts) from byte `at` of `b` on.
pub(crate) fn be_i32x6(b: &[u8], at: usize) -> [i32; 6] {
    std::array::from_fn(|k| be_u32(b, at + 4 * k) as i32)
}

/// Writes six `i32` big-endian into `b` from byte `at` on.
pub(crate) fn put_be_i32x6(b: &mut [u8], at: usize, values: &[i32; 6]) {
    for (k, v) in values.iter().enumerate() {
        b[at + 4 * k..at + 4 * k + 4].copy_from_slice(&v.to_be_bytes());
    }
}
