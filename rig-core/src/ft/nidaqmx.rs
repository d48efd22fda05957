//! ATI's DAQ F/T route through NI-DAQmx, without I/O: the constants and error codes of NI's C
//! API that the rig's reader uses, what each error means for an operator, and NI's
//! physical-channel syntax (`Dev1/ai0:5`).
//!
//! The Nano17's six strain-gauge amplifier outputs (plus a thermistor on sensors calibrated
//! for software temperature compensation) are wired to an NI data-acquisition card, ATI's
//! default being differential inputs. The host samples them with NI-DAQmx and applies the
//! sensor's `.cal` file itself (`F = M · (V − bias)`, see [`super::cal`]). The rig's reader
//! (`rig::force::nidaqmx`) loads NI's library at run time; this module holds the numbers it
//! passes and receives, from NI's header `NIDAQmx.h` (on Linux x86_64 `int32` is C `int`,
//! `uInt32` `unsigned int`, `uInt64` `unsigned long long`, `float64` `double`, `bool32`
//! `uInt32`, `TaskHandle` `void*`). Every function returns an `int32` status: 0 success,
//! negative an error, positive a warning.

use std::fmt;

/// `DAQmx_Val_*` values from `NIDAQmx.h`.
pub mod val {
    /// `DAQmx_Val_Cfg_Default`: the card's default terminal configuration.
    pub const CFG_DEFAULT: i32 = -1;
    /// `DAQmx_Val_Diff`: differential inputs (ATI's default wiring).
    pub const DIFF: i32 = 10106;
    /// `DAQmx_Val_RSE`: referenced single-ended.
    pub const RSE: i32 = 10083;
    /// `DAQmx_Val_NRSE`: non-referenced single-ended.
    pub const NRSE: i32 = 10078;
    /// `DAQmx_Val_Volts`.
    pub const VOLTS: i32 = 10348;
    /// `DAQmx_Val_Rising`.
    pub const RISING: i32 = 10280;
    /// `DAQmx_Val_ContSamps`: continuous, hardware-timed acquisition.
    pub const CONT_SAMPS: i32 = 10123;
    /// `DAQmx_Val_FiniteSamps`.
    pub const FINITE_SAMPS: i32 = 10178;
    /// `DAQmx_Val_GroupByChannel`: all of channel 0's samples, then channel 1's, ...
    pub const GROUP_BY_CHANNEL: u32 = 0;
    /// `DAQmx_Val_GroupByScanNumber`: one scan (every channel) after the other.
    pub const GROUP_BY_SCAN_NUMBER: u32 = 1;
    /// `DAQmx_Val_WaitInfinitely` (a read timeout, seconds).
    pub const WAIT_INFINITELY: f64 = -1.0;
    /// `DAQmx_Val_OverwriteUnreadSamps` (`DAQmx_Read_OverWrite`): the card keeps acquiring
    /// when the host falls behind, and a read of overwritten samples fails with
    /// [`super::code::SAMPLES_NO_LONGER_AVAILABLE`].
    pub const OVERWRITE_UNREAD_SAMPS: i32 = 10252;
    /// `DAQmx_Val_DoNotOverwriteUnreadSamps` (NI's default).
    pub const DO_NOT_OVERWRITE_UNREAD_SAMPS: i32 = 10159;
    /// `DAQmx_Val_FirstSample` (`DAQmx_Read_RelativeTo`).
    pub const FIRST_SAMPLE: i32 = 10424;
    /// `DAQmx_Val_CurrReadPos` (`DAQmx_Read_RelativeTo`, NI's default).
    pub const CURR_READ_POS: i32 = 10425;
    /// `DAQmx_Val_MostRecentSamp` (`DAQmx_Read_RelativeTo`).
    pub const MOST_RECENT_SAMP: i32 = 10428;
}

/// NI-DAQmx error codes the reader acts on.
pub mod code {
    /// Samples no longer available: the buffer was overwritten before they were read.
    pub const SAMPLES_NO_LONGER_AVAILABLE: i32 = -200279;
    /// Samples not yet available within the read's timeout.
    pub const SAMPLES_NOT_YET_AVAILABLE: i32 = -200284;
    /// Input FIFO overflow (the card's onboard memory).
    pub const INPUT_FIFO_OVERFLOW: i32 = -200010;
    /// Onboard device memory overflow.
    pub const INPUT_FIFO_OVERFLOW_2: i32 = -200361;
    /// The device was removed.
    pub const DEVICE_REMOVED: i32 = -200045;
    /// The device is absent or unavailable.
    pub const DEVICE_ABSENT: i32 = -200324;
    /// Invalid device identifier.
    pub const INVALID_DEVICE_ID: i32 = -200220;
    /// The physical channel does not exist on the device.
    pub const PHYSICAL_CHANNEL_DOES_NOT_EXIST: i32 = -200170;
    /// The resource is already reserved (another task or program uses the card).
    pub const RESOURCE_RESERVED: i32 = -200022;
}

/// What an NI-DAQmx status means for the reader.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ErrorClass {
    /// Success (0).
    Ok,
    /// A warning (> 0): the call did its work.
    Warning,
    /// The host fell behind and the card overwrote unread samples: count them as lost and
    /// read on from the oldest sample still held.
    Overrun,
    /// The card's onboard memory overflowed and the acquisition stopped: restart it.
    FifoOverflow,
    /// No samples within the read's timeout.
    Timeout,
    /// The device was removed or is unavailable: the stream has ended.
    DeviceGone,
    /// Any other error: the configuration or the driver refused something.
    Fatal,
}

/// Classifies an NI-DAQmx status.
pub fn classify(status: i32) -> ErrorClass {
    match status {
        0 => ErrorClass::Ok,
        s if s > 0 => ErrorClass::Warning,
        code::SAMPLES_NO_LONGER_AVAILABLE => ErrorClass::Overrun,
        code::INPUT_FIFO_OVERFLOW | code::INPUT_FIFO_OVERFLOW_2 => ErrorClass::FifoOverflow,
        code::SAMPLES_NOT_YET_AVAILABLE => ErrorClass::Timeout,
        code::DEVICE_REMOVED | code::DEVICE_ABSENT => ErrorClass::DeviceGone,
        _ => ErrorClass::Fatal,
    }
}

/// What an operator can do about the common NI-DAQmx errors (NI's own message says what
/// happened; this says what to check).
pub fn hint(status: i32) -> Option<&'static str> {
    Some(match status {
        code::SAMPLES_NO_LONGER_AVAILABLE => {
            "the host read too slowly and the card overwrote samples (counted as lost); a busy \
             machine or a stalled process"
        }
        code::SAMPLES_NOT_YET_AVAILABLE => {
            "no samples arrived in time: is the card's sample clock running (an external clock \
             or trigger not connected)?"
        }
        code::INPUT_FIFO_OVERFLOW | code::INPUT_FIFO_OVERFLOW_2 => {
            "the card's onboard memory overflowed: the bus could not keep up (a USB card on a \
             shared hub, or too high a rate for the number of channels)"
        }
        code::DEVICE_REMOVED | code::DEVICE_ABSENT => {
            "the card is gone: check its USB or PCIe connection and power, and that it shows \
             in NI MAX / `nilsdev`"
        }
        code::INVALID_DEVICE_ID => {
            "no device has that name: list the devices with `nilsdev` (or NI MAX) and set \
             force_sensor.channels to match (e.g. \"Dev1/ai0:5\")"
        }
        code::PHYSICAL_CHANNEL_DOES_NOT_EXIST => {
            "the card has no such channel: check force_sensor.channels and \
             force_sensor.thermistor_channel against the card's analog inputs"
        }
        code::RESOURCE_RESERVED => {
            "another task or program is using the card: close NI MAX test panels, other rigs, \
             or a previous run still holding it"
        }
        _ => return None,
    })
}

/// The input terminal configuration of the gauge channels (`force_sensor.terminal_config`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TerminalConfig {
    /// Differential (ATI's default wiring): `DAQmx_Val_Diff`.
    #[default]
    Differential,
    /// Referenced single-ended: `DAQmx_Val_RSE`.
    Rse,
    /// Non-referenced single-ended: `DAQmx_Val_NRSE`.
    Nrse,
    /// The card's default for the channel: `DAQmx_Val_Cfg_Default`.
    Default,
}

impl TerminalConfig {
    /// The `DAQmx_Val_*` value passed to `DAQmxCreateAIVoltageChan`.
    pub fn value(self) -> i32 {
        match self {
            TerminalConfig::Differential => val::DIFF,
            TerminalConfig::Rse => val::RSE,
            TerminalConfig::Nrse => val::NRSE,
            TerminalConfig::Default => val::CFG_DEFAULT,
        }
    }
}

/// The gauge channels ATI's software and the TransForce authors' collection code use.
pub const DEFAULT_CHANNELS: &str = "Dev1/ai0:5";

/// Sample rates below this are refused for the NI route, Hz (ATI's demo samples at 1 kHz; the
/// rig's sync needs at least that).
pub const MIN_RATE_HZ: f64 = 1000.0;

/// One analog-input physical channel, `DEVICE/aiN`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PhysicalChannel {
    /// The device (or chassis module) name, e.g. `Dev1`, `cDAQ1Mod1`.
    pub device: String,
    /// The analog input number N of `aiN`.
    pub index: u32,
}

impl fmt::Display for PhysicalChannel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}/ai{}", self.device, self.index)
    }
}

/// Why a physical-channel string could not be read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{text:?}: {reason} (expected NI's syntax, e.g. \"Dev1/ai0:5\" or \"Dev1/ai0, Dev1/ai2\")")]
pub struct ChannelSyntaxError {
    pub text: String,
    pub reason: String,
}

/// Expands NI's physical-channel list syntax, as `DAQmxCreateAIVoltageChan` takes it: entries
/// separated by commas, each `DEVICE/aiN` or a range `DEVICE/aiN:M` (ascending or
/// descending; the range's end may repeat the device and `ai`, `Dev1/ai0:Dev1/ai5`).
pub fn parse_channels(text: &str) -> Result<Vec<PhysicalChannel>, ChannelSyntaxError> {
    let bad = |reason: &str| ChannelSyntaxError {
        text: text.to_owned(),
        reason: reason.to_owned(),
    };
    let mut out = Vec::new();
    for entry in text.split(',').map(str::trim) {
        if entry.is_empty() {
            return Err(bad("an empty entry"));
        }
        let (head, tail) = match entry.split_once(':') {
            Some((h, t)) => (h.trim(), Some(t.trim())),
            None => (entry, None),
        };
        let (device, first) = head
            .rsplit_once('/')
            .filter(|(d, _)| !d.trim().is_empty())
            .ok_or_else(|| bad("an entry without a device name (DEVICE/aiN)"))?;
        if device.contains(char::is_whitespace) {
            return Err(bad("a device name with spaces"));
        }
        let number = |s: &str, what: &str| -> Result<u32, ChannelSyntaxError> {
            s.parse::<u32>()
                .map_err(|_| bad(&format!("{what} is not a number")))
        };
        let first = first
            .strip_prefix("ai")
            .ok_or_else(|| bad("not an analog input (aiN)"))?;
        let a = number(first, "a channel number")?;
        let b = match tail {
            None => a,
            Some(t) => {
                // `Dev1/ai0:Dev1/ai5` names the device again; `Dev1/ai0:5` does not.
                let t = match t.rsplit_once('/') {
                    Some((d, t)) if d == device => t,
                    Some(_) => return Err(bad("a range across two devices")),
                    None => t,
                };
                number(t.strip_prefix("ai").unwrap_or(t), "a range end")?
            }
        };
        let range: Box<dyn Iterator<Item = u32>> = if a <= b {
            Box::new(a..=b)
        } else {
            Box::new((b..=a).rev())
        };
        for index in range {
            if out.len() >= 1024 {
                return Err(bad("more than 1024 channels"));
            }
            out.push(PhysicalChannel {
                device: device.to_owned(),
                index,
            });
        }
    }
    Ok(out)
}

/// The thermistor's channel when none is configured: the input after the last gauge channel
/// on the same device (`Dev1/ai0:5` → `Dev1/ai6`, ATI's wiring of a 7-channel sensor).
pub fn default_thermistor_channel(gauges: &[PhysicalChannel]) -> Option<PhysicalChannel> {
    let last = gauges.last()?;
    Some(PhysicalChannel {
        device: last.device.clone(),
        index: last.index.checked_add(1)?,
    })
}

/// The problems with a set of gauge channels and an optional thermistor channel: exactly six
/// gauges, no channel twice.
pub fn check_channels(
    gauges: &str,
    thermistor: Option<&str>,
) -> Result<(Vec<PhysicalChannel>, Option<PhysicalChannel>), String> {
    let g = parse_channels(gauges).map_err(|e| e.to_string())?;
    if g.len() != 6 {
        return Err(format!(
            "{gauges:?} names {} channels; the Nano17 has six gauges (e.g. \"Dev1/ai0:5\")",
            g.len()
        ));
    }
    for (i, c) in g.iter().enumerate() {
        if g[..i].contains(c) {
            return Err(format!("{gauges:?} names {c} twice"));
        }
    }
    let t = match thermistor {
        None => None,
        Some(t) => {
            let mut v = parse_channels(t).map_err(|e| e.to_string())?;
            if v.len() != 1 {
                return Err(format!(
                    "thermistor channel {t:?} names {} channels; give one (e.g. \"Dev1/ai6\")",
                    v.len()
                ));
            }
            let c = v.remove(0);
            if g.contains(&c) {
                return Err(format!("thermistor channel {c} is also a gauge channel"));
            }
            Some(c)
        }
    };
    Ok((g, t))
}

/// Joins channels back into NI's list syntax (`Dev1/ai0, Dev1/ai1, ...`).
pub fn join_channels(channels: &[PhysicalChannel]) -> String {
    channels
        .iter()
        .map(ToString::to_string)
        .collect::<Vec<_>>()
        .join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names(text: &str) -> Vec<String> {
        parse_channels(text)
            .unwrap()
            .iter()
            .map(ToString::to_string)
            .collect()
    }

    #[test]
    fn ranges_lists_and_repeated_device_names_expand_like_ni() {
        assert_eq!(
            names("Dev1/ai0:5"),
            [
                "Dev1/ai0", "Dev1/ai1", "Dev1/ai2", "Dev1/ai3", "Dev1/ai4", "Dev1/ai5"
            ]
        );
        assert_eq!(names("Dev2/ai3:1"), ["Dev2/ai3", "Dev2/ai2", "Dev2/ai1"]);
        assert_eq!(
            names("cDAQ1Mod1/ai0:cDAQ1Mod1/ai1"),
            ["cDAQ1Mod1/ai0", "cDAQ1Mod1/ai1"]
        );
        assert_eq!(
            names("Dev1/ai0, Dev1/ai2,Dev1/ai4:5"),
            ["Dev1/ai0", "Dev1/ai2", "Dev1/ai4", "Dev1/ai5"]
        );
        assert_eq!(names("Dev1/ai0:Dev1/ai1"), ["Dev1/ai0", "Dev1/ai1"]);
    }

    #[test]
    fn malformed_channel_strings_are_refused_with_the_reason() {
        for (text, why) in [
            ("ai0:5", "device"),
            ("Dev1/ao0", "analog input"),
            ("Dev1/aiX", "number"),
            ("Dev1/ai0:x", "range end"),
            ("Dev1/ai0,,Dev1/ai1", "empty"),
            ("Dev1/ai0:Dev2/ai5", "two devices"),
        ] {
            let e = parse_channels(text).unwrap_err().to_string();
            assert!(e.contains(why), "{text}: {e}");
        }
    }

    #[test]
    fn six_distinct_gauges_and_a_separate_thermistor_are_required() {
        let (g, t) = check_channels("Dev1/ai0:5", Some("Dev1/ai6")).unwrap();
        assert_eq!(g.len(), 6);
        assert_eq!(t.unwrap().index, 6);
        assert_eq!(
            default_thermistor_channel(&g).unwrap().to_string(),
            "Dev1/ai6"
        );
        assert!(
            check_channels("Dev1/ai0:4", None)
                .unwrap_err()
                .contains("5 channels")
        );
        assert!(
            check_channels("Dev1/ai0:4, Dev1/ai4", None)
                .unwrap_err()
                .contains("twice")
        );
        assert!(
            check_channels("Dev1/ai0:5", Some("Dev1/ai3"))
                .unwrap_err()
                .contains("also a gauge")
        );
    }

    #[test]
    fn errors_are_classified_and_the_common_ones_have_hints() {
        assert_eq!(classify(0), ErrorClass::Ok);
        assert_eq!(classify(200_000), ErrorClass::Warning);
        assert_eq!(classify(-200279), ErrorClass::Overrun);
        assert_eq!(classify(-200361), ErrorClass::FifoOverflow);
        assert_eq!(classify(-200010), ErrorClass::FifoOverflow);
        assert_eq!(classify(-200284), ErrorClass::Timeout);
        assert_eq!(classify(-200045), ErrorClass::DeviceGone);
        assert_eq!(classify(-200324), ErrorClass::DeviceGone);
        assert_eq!(classify(-200170), ErrorClass::Fatal);
        for c in [
            -200279, -200284, -200010, -200361, -200045, -200324, -200220, -200170, -200022,
        ] {
            assert!(hint(c).is_some(), "{c}");
        }
        assert!(hint(-1).is_none());
    }
}
