//! The NI-DAQmx calls on the simulated card's tasks: channels, timing, buffer and read
//! position, start and stop, and `DAQmxReadAnalogF64` (see the parent module for the card's
//! behaviour, `card` for its state).

use std::time::{Duration, Instant};

use rig_core::ft::nidaqmx::val;

use super::card::{
    AI_CHANNELS, Channel, DEFAULT_BUFFER, Device, Inner, MAX_AGGREGATE_RATE, RANGES_V, ReadOutcome,
    Run, System, Task, Wire, unknown_device, wire,
};
use super::errors::{self, Fail};
use super::hook::{FAULT_BIT_OVERLOAD, FAULT_BIT_REMOVED, LOG_WIDTH};

/// `DAQmx_Val_Falling`.
const FALLING: i32 = 10171;
/// A read that waits this long in real time without its clock reaching the samples gives up
/// with a timeout, whatever its own timeout (a simulator's clock that stopped for good).
const REAL_TIME_GUARD: Duration = Duration::from_secs(60);

fn invalid_task(handle: u64) -> Fail {
    Fail::new(errors::INVALID_TASK, format!("Task Handle: {handle:#x}"))
}

impl Inner {
    /// The task behind `handle`, or NI's invalid-task error.
    fn task_mut(&mut self, handle: u64) -> Result<&mut Task, Fail> {
        self.tasks
            .get_mut(&handle)
            .ok_or_else(|| invalid_task(handle))
    }
}

impl System {
    /// `DAQmxCreateTask`.
    pub fn create_task(&self, name: &str) -> Result<u64, Fail> {
        let mut g = self.lock();
        let h = g.new_handle();
        let name = if name.is_empty() {
            format!("_unnamedTask<{}>", h - 1)
        } else {
            name.to_owned()
        };
        g.tasks.insert(
            h,
            Task {
                name,
                device: None,
                channels: Vec::new(),
                rate_hz: None,
                finite: None,
                buffer: None,
                overwrite: false,
                relative_to: val::CURR_READ_POS,
                offset: 0,
                run: None,
            },
        );
        Ok(h)
    }

    /// `DAQmxCreateAIVoltageChan` (volts only, no custom scale).
    #[allow(clippy::too_many_arguments)]
    pub fn create_ai_voltage_chan(
        &self,
        handle: u64,
        physical: &str,
        terminal: i32,
        min_v: f64,
        max_v: f64,
        units: i32,
        custom_scale: &str,
    ) -> Result<(), Fail> {
        let mut g = self.lock();
        let inner = &mut *g;
        let task = inner
            .tasks
            .get_mut(&handle)
            .ok_or_else(|| invalid_task(handle))?;
        let ctx = |what: String| format!("{what}\nTask Name: {}", task.name);
        let bad_value = |what: String| Fail::new(errors::INVALID_ATTRIBUTE_VALUE, what);
        if ![val::DIFF, val::RSE, val::NRSE, val::CFG_DEFAULT].contains(&terminal) {
            return Err(bad_value(ctx(format!(
                "Property: DAQmx_AI_TermCfg\nRequested Value: {terminal}"
            ))));
        }
        if units != val::VOLTS || !custom_scale.is_empty() {
            return Err(bad_value(ctx(format!(
                "Property: DAQmx_AI_VoltageUnits\nRequested Value: {units} {custom_scale:?}"
            ))));
        }
        let span = min_v.abs().max(max_v.abs());
        let range_v = match RANGES_V.iter().find(|r| span <= **r + 1e-12) {
            Some(r) if min_v.is_finite() && max_v.is_finite() && min_v < max_v => *r,
            _ => {
                return Err(bad_value(ctx(format!(
                    "Property: DAQmx_AI_Max / DAQmx_AI_Min\nRequested Value: {min_v} .. {max_v}\n\
                     Possible Values: -10 .. 10"
                ))));
            }
        };
        let mut added = Vec::new();
        for entry in physical.split(',').map(str::trim) {
            let (device, ais) = parse_entry(entry).ok_or_else(|| {
                Fail::new(
                    errors::PHYSICAL_CHANNEL_DOES_NOT_EXIST,
                    ctx(format!("Physical Channel Name: {entry}")),
                )
            })?;
            let dev = inner.devices.get(device).ok_or_else(|| {
                let mut f = unknown_device(device);
                f.message.push_str(&format!("\nTask Name: {}", task.name));
                f
            })?;
            if dev.removed {
                return Err(Fail::new(
                    errors::DEVICE_ABSENT,
                    ctx(format!("Device: {device}")),
                ));
            }
            if task.device.as_deref().is_some_and(|d| d != device) {
                return Err(bad_value(ctx(format!(
                    "Physical Channel Name: {entry}\nthis card's tasks take the channels of one \
                     device"
                ))));
            }
            for ai in ais {
                if ai >= AI_CHANNELS {
                    return Err(Fail::new(
                        errors::PHYSICAL_CHANNEL_DOES_NOT_EXIST,
                        ctx(format!(
                            "Physical Channel Name: {device}/ai{ai}\nDevice: {device}\n\
                             Possible Values: {device}/ai0:{}",
                            AI_CHANNELS - 1
                        )),
                    ));
                }
                added.push(Channel { ai, range_v });
            }
            task.device = Some(device.to_owned());
        }
        task.channels.extend(added);
        Ok(())
    }

    /// `DAQmxCfgSampClkTiming` on the onboard clock.
    pub fn cfg_samp_clk_timing(
        &self,
        handle: u64,
        source: &str,
        rate_hz: f64,
        active_edge: i32,
        sample_mode: i32,
        samps_per_chan: u64,
    ) -> Result<(), Fail> {
        let mut g = self.lock();
        let task = g.task_mut(handle)?;
        let nch = task.channels.len().max(1) as f64;
        let bad = |what: String| Fail::new(errors::INVALID_ATTRIBUTE_VALUE, what);
        if !(source.is_empty() || source == "OnboardClock") {
            return Err(bad(format!(
                "Property: DAQmx_SampClk_Src\nRequested Value: {source}\nthis card's stand-in \
                 has its onboard clock only"
            )));
        }
        if !(rate_hz.is_finite() && rate_hz > 0.0 && rate_hz * nch <= MAX_AGGREGATE_RATE) {
            return Err(bad(format!(
                "Property: DAQmx_SampClk_Rate\nRequested Value: {rate_hz}\nMaximum: {} per \
                 channel with {nch} channels",
                MAX_AGGREGATE_RATE / nch
            )));
        }
        if active_edge != val::RISING && active_edge != FALLING {
            return Err(bad(format!(
                "Property: DAQmx_SampClk_ActiveEdge\nRequested Value: {active_edge}"
            )));
        }
        task.finite = match sample_mode {
            val::CONT_SAMPS => None,
            val::FINITE_SAMPS => Some(samps_per_chan.max(1)),
            other => {
                return Err(bad(format!(
                    "Property: DAQmx_SampQuant_SampMode\nRequested Value: {other}"
                )));
            }
        };
        task.rate_hz = Some(rate_hz);
        if task.buffer.is_none() && sample_mode == val::CONT_SAMPS {
            task.buffer = Some(samps_per_chan.max(DEFAULT_BUFFER));
        }
        Ok(())
    }

    /// `DAQmxCfgInputBuffer`.
    pub fn cfg_input_buffer(&self, handle: u64, samps_per_chan: u32) -> Result<(), Fail> {
        let mut g = self.lock();
        let task = g.task_mut(handle)?;
        task.buffer = Some(u64::from(samps_per_chan.max(2)));
        Ok(())
    }

    /// `DAQmxSetReadOverWrite`.
    pub fn set_read_overwrite(&self, handle: u64, mode: i32) -> Result<(), Fail> {
        let mut g = self.lock();
        let task = g.task_mut(handle)?;
        task.overwrite = match mode {
            val::OVERWRITE_UNREAD_SAMPS => true,
            val::DO_NOT_OVERWRITE_UNREAD_SAMPS => false,
            other => {
                return Err(Fail::new(
                    errors::INVALID_ATTRIBUTE_VALUE,
                    format!("Property: DAQmx_Read_OverWrite\nRequested Value: {other}"),
                ));
            }
        };
        Ok(())
    }

    /// `DAQmxSetReadRelativeTo`.
    pub fn set_read_relative_to(&self, handle: u64, to: i32) -> Result<(), Fail> {
        let mut g = self.lock();
        let task = g.task_mut(handle)?;
        if ![val::CURR_READ_POS, val::FIRST_SAMPLE, val::MOST_RECENT_SAMP].contains(&to) {
            return Err(Fail::new(
                errors::INVALID_ATTRIBUTE_VALUE,
                format!("Property: DAQmx_Read_RelativeTo\nRequested Value: {to}"),
            ));
        }
        task.relative_to = to;
        Ok(())
    }

    /// `DAQmxSetReadOffset`.
    pub fn set_read_offset(&self, handle: u64, offset: i32) -> Result<(), Fail> {
        let mut g = self.lock();
        let task = g.task_mut(handle)?;
        task.offset = offset;
        Ok(())
    }

    /// `DAQmxStartTask`.
    pub fn start_task(&self, handle: u64) -> Result<(), Fail> {
        let mut g = self.lock();
        start_locked(&mut g, handle)
    }

    /// `DAQmxStopTask`. An injected FIFO overflow has fired by then: a restart acquires again.
    pub fn stop_task(&self, handle: u64) -> Result<(), Fail> {
        let mut g = self.lock();
        let inner = &mut *g;
        let task = inner
            .tasks
            .get_mut(&handle)
            .ok_or_else(|| invalid_task(handle))?;
        let name = task.device.clone().unwrap_or_default();
        let mut removed = false;
        if task.run.is_some()
            && let Some(dev) = inner.devices.get_mut(&name)
        {
            dev.stats.acquired = task.acquired(dev, dev.now_ns());
            if dev.reserved_by == Some(handle) {
                dev.reserved_by = None;
            }
            dev.injections.fifo_at = None;
            dev.acquiring(false);
            removed = dev.removed;
        }
        task.run = None;
        if removed {
            return Err(Fail::new(errors::DEVICE_REMOVED, format!("Device: {name}")));
        }
        Ok(())
    }

    /// `DAQmxClearTask`: stops the task and forgets it.
    pub fn clear_task(&self, handle: u64) -> Result<(), Fail> {
        let _ = self.stop_task(handle);
        let mut g = self.lock();
        g.tasks
            .remove(&handle)
            .map(|_| ())
            .ok_or_else(|| invalid_task(handle))
    }

    /// `DAQmxGetReadTotalSampPerChanAcquired`.
    pub fn total_acquired(&self, handle: u64) -> Result<u64, Fail> {
        let g = self.lock();
        let task = g.tasks.get(&handle).ok_or_else(|| invalid_task(handle))?;
        Ok(
            match task.device.as_deref().and_then(|d| g.devices.get(d)) {
                Some(dev) => task.acquired(dev, dev.now_ns()),
                None => 0,
            },
        )
    }

    /// `DAQmxReadAnalogF64`: `n` samples per channel (−1: all acquired and unread), waiting up
    /// to `timeout_s` of the device's clock (negative: forever), into `out` grouped by channel
    /// (`fill_mode` 0) or by scan (1).
    pub fn read_analog_f64(
        &self,
        handle: u64,
        n: i32,
        timeout_s: f64,
        fill_mode: u32,
        out: &mut [f64],
    ) -> ReadOutcome {
        let fail = |e: Fail| ReadOutcome {
            read: 0,
            error: Some(e),
        };
        // Where the read starts, how much it takes, until when it waits.
        let (pos, n, deadline, stall_until) = {
            let mut g = self.lock();
            let inner = &mut *g;
            let Some(task) = inner.tasks.get(&handle) else {
                return fail(invalid_task(handle));
            };
            if task.run.is_none()
                && let Err(e) = start_locked(inner, handle)
            {
                return fail(e);
            }
            let (Some(task), Some(dev)) = (
                inner.tasks.get(&handle),
                inner
                    .devices
                    .get_mut(inner.tasks[&handle].device.as_deref().unwrap_or("")),
            ) else {
                return fail(invalid_task(handle));
            };
            let run = task.run.as_ref().expect("started above");
            if let Some(e) = &run.error {
                return fail(e.clone());
            }
            let now = dev.now_ns();
            let acquired = task.acquired(dev, now);
            let pos = match task.relative_to {
                val::FIRST_SAMPLE => i128::from(task.offset),
                val::MOST_RECENT_SAMP => i128::from(acquired) + i128::from(task.offset),
                _ => i128::from(run.read_pos) + i128::from(task.offset),
            };
            let Ok(pos) = u64::try_from(pos) else {
                return fail(Fail::new(
                    errors::INVALID_ATTRIBUTE_VALUE,
                    format!(
                        "Property: DAQmx_Read_Offset\nRequested Value: {}",
                        task.offset
                    ),
                ));
            };
            let n = if n < 0 {
                acquired.saturating_sub(pos)
            } else {
                n as u64
            };
            let nch = task.channels.len() as u64;
            if nch == 0 || (out.len() as u64) < n.saturating_mul(nch) {
                return fail(Fail::new(
                    errors::READ_BUFFER_TOO_SMALL,
                    format!(
                        "Array Size: {} values\nRequired: {n} samples × {nch} channels\nTask \
                         Name: {}",
                        out.len(),
                        task.name
                    ),
                ));
            }
            let mut stall_until = 0;
            if let Some(at) = dev.injections.overrun_at
                && pos + n > at
            {
                // The host stalls here until the card has wrapped its buffer past `pos`.
                dev.injections.overrun_at = None;
                stall_until = pos + task.buffer() + task.buffer() / 2;
            }
            let deadline = if timeout_s < 0.0 || !timeout_s.is_finite() {
                u64::MAX
            } else {
                now.saturating_add((timeout_s * 1e9) as u64)
            };
            (pos, n, deadline, stall_until)
        };
        // The device's clock may run faster than real time: its measured rate turns a wait in
        // clock time into a sleep in real time.
        let started = Instant::now();
        loop {
            let (wait_ns, rate) = {
                let mut g = self.lock();
                match self.try_read(
                    &mut g,
                    handle,
                    pos,
                    n,
                    deadline,
                    stall_until,
                    fill_mode,
                    out,
                ) {
                    Step::Done(o) => return o,
                    Step::Wait { clock_ns, rate } => (clock_ns, rate),
                }
            };
            if started.elapsed() > REAL_TIME_GUARD {
                return fail(Fail::new(
                    errors::SAMPLES_NOT_YET_AVAILABLE,
                    "the device's clock did not reach the samples within a minute of real time",
                ));
            }
            let sleep = (wait_ns as f64 / rate.max(1e-3)).clamp(20_000.0, 1_000_000.0);
            std::thread::sleep(Duration::from_nanos(sleep as u64));
        }
    }

    /// One look at the card for a read: done (data or an error) or how long to wait.
    #[allow(clippy::too_many_arguments)]
    fn try_read(
        &self,
        inner: &mut Inner,
        handle: u64,
        pos: u64,
        n: u64,
        deadline: u64,
        stall_until: u64,
        fill_mode: u32,
        out: &mut [f64],
    ) -> Step {
        let Some(task) = inner.tasks.get_mut(&handle) else {
            return Step::Done(ReadOutcome {
                read: 0,
                error: Some(invalid_task(handle)),
            });
        };
        let name = task.device.clone().unwrap_or_default();
        let Some(dev) = inner.devices.get_mut(&name) else {
            return Step::Done(ReadOutcome {
                read: 0,
                error: Some(unknown_device(&name)),
            });
        };
        let done = |read, e: Option<Fail>| Step::Done(ReadOutcome { read, error: e });
        if task.run.is_none() {
            return done(0, Some(invalid_task(handle)));
        }
        let now = dev.now_ns();
        let bits = dev.fault_bits();
        if bits & FAULT_BIT_REMOVED != 0 && dev.injections.remove_at.is_none() {
            dev.injections.remove_at = Some(task.ticked(now));
        }
        let overload = bits & FAULT_BIT_OVERLOAD != 0;
        let ticked = task.ticked(now);
        let removed_at = dev.injections.remove_at.filter(|r| ticked > *r);
        if dev.removed || removed_at.is_some() {
            let end = removed_at.unwrap_or(pos).min(pos + n).max(pos);
            let k = generate(task, dev, pos, end - pos, n, overload, fill_mode, out);
            dev.removed = true;
            let e = Fail::new(errors::DEVICE_REMOVED, format!("Device: {name}"));
            if let Some(run) = task.run.as_mut() {
                run.error = Some(e.clone());
            }
            return done(k, Some(e));
        }
        let acquired = task.acquired(dev, now);
        // An injected host stall: this read returns only once the stall is over.
        if acquired < stall_until {
            return Step::Wait {
                clock_ns: 1_000_000,
                rate: dev.clock_rate(now),
            };
        }
        if pos < acquired.saturating_sub(task.buffer()) {
            let e = Fail::new(
                errors::SAMPLES_NO_LONGER_AVAILABLE,
                format!(
                    "Sample Requested: {pos}\nOldest Sample Available: {}\nBuffer Size: {} \
                     samples per channel\nTask Name: {}",
                    acquired - task.buffer(),
                    task.buffer(),
                    task.name
                ),
            );
            if !task.overwrite
                && let Some(run) = task.run.as_mut()
            {
                run.error = Some(e.clone());
            }
            return done(0, Some(e));
        }
        if acquired >= pos + n {
            let k = generate(task, dev, pos, n, n, overload, fill_mode, out);
            return done(k, None);
        }
        if let Some(h) = dev.injections.fifo_at.filter(|h| ticked > *h) {
            let end = h.clamp(pos, pos + n);
            let k = generate(task, dev, pos, end - pos, n, overload, fill_mode, out);
            let e = Fail::new(errors::INPUT_FIFO_OVERFLOW_2, format!("Device: {name}"));
            if let Some(run) = task.run.as_mut() {
                run.error = Some(e.clone());
            }
            return done(k, Some(e));
        }
        if now >= deadline {
            let avail = acquired.saturating_sub(pos).min(n);
            let k = generate(task, dev, pos, avail, n, overload, fill_mode, out);
            let e = Fail::new(
                errors::SAMPLES_NOT_YET_AVAILABLE,
                format!(
                    "Samples Requested: {n}\nSamples Read: {k}\nTask Name: {}",
                    task.name
                ),
            );
            return done(k, Some(e));
        }
        let run = task.run.as_ref().expect("checked above");
        let due = task.sample_time_ns(run.t0_ns, pos + n - 1);
        Step::Wait {
            clock_ns: due.min(deadline).saturating_sub(now),
            rate: dev.clock_rate(now),
        }
    }
}

enum Step {
    Done(ReadOutcome),
    /// Not yet: wait about `clock_ns` of the device's clock, which runs `rate` times as fast
    /// as real time.
    Wait {
        clock_ns: u64,
        rate: f64,
    },
}

fn start_locked(inner: &mut Inner, handle: u64) -> Result<(), Fail> {
    let task = inner
        .tasks
        .get_mut(&handle)
        .ok_or_else(|| invalid_task(handle))?;
    if task.run.is_some() {
        return Ok(());
    }
    let bad = |what: &str| Fail::new(errors::INVALID_ATTRIBUTE_VALUE, what.to_owned());
    let Some(name) = task.device.clone() else {
        return Err(bad("the task has no channels"));
    };
    if task.rate_hz.is_none() {
        return Err(bad("the task has no sample clock (DAQmxCfgSampClkTiming)"));
    }
    let dev = inner
        .devices
        .get_mut(&name)
        .ok_or_else(|| unknown_device(&name))?;
    if dev.removed {
        return Err(Fail::new(errors::DEVICE_ABSENT, format!("Device: {name}")));
    }
    if let Some(other) = dev.reserved_by.filter(|o| *o != handle) {
        return Err(Fail::new(
            errors::RESOURCE_RESERVED,
            format!(
                "Device: {name}\nTask Name: {}\nReserved by task handle {other:#x}",
                task.name
            ),
        ));
    }
    dev.acquiring(true);
    let t0 = dev.now_ns() + dev.injections.late_start_ns;
    dev.reserved_by = Some(handle);
    dev.stats.first_sample_ns = t0;
    dev.stats.rate_hz = task.rate_hz.unwrap_or(0.0);
    dev.stats.starts += 1;
    dev.stats.acquired = 0;
    if let Some(log) = dev.log.as_mut() {
        log.values.clear();
    }
    task.run = Some(Run {
        t0_ns: t0,
        read_pos: 0,
        error: None,
    });
    Ok(())
}

/// Samples `pos..pos + k` into `out` (a read of `n` per channel, so by-channel blocks are `n`
/// apart), moving the read position past them. Returns `k`.
#[allow(clippy::too_many_arguments)]
fn generate(
    task: &mut Task,
    dev: &mut Device,
    pos: u64,
    k: u64,
    n: u64,
    overload: bool,
    fill_mode: u32,
    out: &mut [f64],
) -> usize {
    let Some(run) = task.run.as_ref() else {
        return 0;
    };
    let t0 = run.t0_ns;
    let nch = task.channels.len();
    for j in 0..k {
        let idx = pos + j;
        let t = task.sample_time_ns(t0, idx);
        let w = dev.wrench_at(t);
        let m = dev.model.measure(&w, overload);
        let mut logged = [f64::NAN; LOG_WIDTH];
        for (c, ch) in task.channels.iter().enumerate() {
            let v = match wire(ch.ai) {
                Wire::Gauge(i) => m.gauges_v[i],
                Wire::Thermistor => m.thermistor_v,
                Wire::Open => 0.0,
            }
            .clamp(-ch.range_v, ch.range_v);
            match wire(ch.ai) {
                Wire::Gauge(i) => logged[i] = v,
                Wire::Thermistor => logged[6] = v,
                Wire::Open => {}
            }
            let at = if fill_mode == val::GROUP_BY_SCAN_NUMBER {
                j as usize * nch + c
            } else {
                c * n as usize + j as usize
            };
            out[at] = v;
        }
        if let Some(log) = dev.log.as_mut()
            && idx < log.max
        {
            let i = idx as usize;
            if log.values.len() <= i {
                log.values.resize(i + 1, [f64::NAN; LOG_WIDTH]);
            }
            log.values[i] = logged;
        }
    }
    if let Some(run) = task.run.as_mut() {
        dev.stats.skipped += pos.saturating_sub(run.read_pos);
        dev.stats.returned += k;
        run.read_pos = run.read_pos.max(pos + k);
    }
    k as usize
}

/// `DEVICE/aiN` or `DEVICE/aiN:M` (the end may repeat `DEVICE/ai`): the device and inputs.
fn parse_entry(entry: &str) -> Option<(&str, Vec<u32>)> {
    let (head, tail) = match entry.split_once(':') {
        Some((h, t)) => (h, Some(t)),
        None => (entry, None),
    };
    let (device, first) = head.rsplit_once('/')?;
    let a: u32 = first.strip_prefix("ai")?.parse().ok()?;
    let b: u32 = match tail {
        None => a,
        Some(t) => {
            let t = match t.rsplit_once('/') {
                Some((d, t)) if d == device => t,
                Some(_) => return None,
                None => t,
            };
            t.strip_prefix("ai").unwrap_or(t).parse().ok()?
        }
    };
    if device.is_empty() || a.max(b) - a.min(b) > 1024 {
        return None;
    }
    let v = if a <= b {
        (a..=b).collect()
    } else {
        (b..=a).rev().collect()
    };
    Some((device, v))
}
