//! A stand-in for NI-DAQmx's C library (`libnidaqmx.so`): the functions the rig's NI reader
//! calls, with NI's names, C types and status codes, over the simulated NI card of
//! `hardware_mocks::nano17::nidaqmx` (the Nano17 wired to `Dev1/ai0:6`). The rig loads it with
//! `dlopen` exactly as it loads NI's library: set `RIG_NIDAQMX_LIBRARY` (or
//! `force_sensor.library`) to this crate's `libnidaqmx_standin.so`.
//!
//! NI's functions (`NIDAQmx.h`; on Linux x86_64 `int32` is `int`):
//!
//! ```text
//! DAQmxCreateTask  DAQmxCreateAIVoltageChan  DAQmxCfgSampClkTiming  DAQmxCfgInputBuffer
//! DAQmxSetReadOverWrite  DAQmxSetReadRelativeTo  DAQmxSetReadOffset
//! DAQmxStartTask  DAQmxStopTask  DAQmxClearTask  DAQmxReadAnalogF64
//! DAQmxGetReadTotalSampPerChanAcquired  DAQmxGetExtendedErrorInfo  DAQmxGetErrorString
//! ```
//!
//! The stand-in's own (`standin_*`, see `hardware_mocks::nano17::nidaqmx::hook`): a simulator
//! attaches its clock, true wrench and faults to a device; a test injects faults (overrun,
//! removal, FIFO overflow, late start at a sample), keeps a log of the voltages read, and reads
//! the card's counters. Nothing here unwinds into C: a panic is caught and returned as an
//! error status.

use std::ffi::{CStr, c_char, c_void};
use std::panic::{AssertUnwindSafe, catch_unwind};

use hardware_mocks::nano17::nidaqmx::System;
use hardware_mocks::nano17::nidaqmx::errors::{self, Fail};
use hardware_mocks::nano17::nidaqmx::hook::{LOG_WIDTH, StandinHook, StandinStats};

/// NI's `TaskHandle`.
pub type TaskHandle = *mut c_void;

fn text<'a>(p: *const c_char) -> std::borrow::Cow<'a, str> {
    if p.is_null() {
        return "".into();
    }
    // SAFETY: NI's API takes NUL-terminated strings; the caller passes one.
    unsafe { CStr::from_ptr(p) }.to_string_lossy()
}

fn handle(t: TaskHandle) -> u64 {
    t as usize as u64
}

/// Runs `f`, turning an error (or a panic) into NI's status and the thread's error text.
fn status(f: impl FnOnce() -> Result<(), Fail>) -> i32 {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(Ok(())) => 0,
        Ok(Err(e)) => errors::record(&e),
        Err(_) => errors::record(&Fail::new(
            errors::INVALID_ATTRIBUTE_VALUE,
            "the NI-DAQmx stand-in failed inside this call (a bug in the stand-in)",
        )),
    }
}

/// Copies `s` into a C buffer of `size` bytes (NUL-terminated, cut to fit). With `size` 0,
/// returns the size needed, as NI does.
fn copy_out(s: &str, buf: *mut c_char, size: u32) -> i32 {
    if size == 0 || buf.is_null() {
        return i32::try_from(s.len() + 1).unwrap_or(i32::MAX);
    }
    let n = s.len().min(size as usize - 1);
    // SAFETY: the caller gives a buffer of `size` bytes; n + 1 <= size.
    unsafe {
        std::ptr::copy_nonoverlapping(s.as_ptr(), buf.cast::<u8>(), n);
        *buf.add(n) = 0;
    }
    0
}

fn sys() -> &'static System {
    System::global()
}

/// # Safety
/// `task` must point to a writable `TaskHandle`; `name` is NULL or a C string.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn DAQmxCreateTask(name: *const c_char, task: *mut TaskHandle) -> i32 {
    status(|| {
        let h = sys().create_task(&text(name))?;
        if !task.is_null() {
            // SAFETY: the caller passes a writable handle.
            unsafe { *task = h as usize as TaskHandle };
        }
        Ok(())
    })
}

/// # Safety
/// The strings are NULL or C strings.
#[allow(clippy::too_many_arguments)]
#[unsafe(no_mangle)]
pub unsafe extern "C" fn DAQmxCreateAIVoltageChan(
    task: TaskHandle,
    physical_channel: *const c_char,
    _name_to_assign: *const c_char,
    terminal_config: i32,
    min_val: f64,
    max_val: f64,
    units: i32,
    custom_scale_name: *const c_char,
) -> i32 {
    status(|| {
        sys().create_ai_voltage_chan(
            handle(task),
            &text(physical_channel),
            terminal_config,
            min_val,
            max_val,
            units,
            &text(custom_scale_name),
        )
    })
}

/// # Safety
/// `source` is NULL or a C string.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn DAQmxCfgSampClkTiming(
    task: TaskHandle,
    source: *const c_char,
    rate: f64,
    active_edge: i32,
    sample_mode: i32,
    samps_per_chan: u64,
) -> i32 {
    status(|| {
        sys().cfg_samp_clk_timing(
            handle(task),
            &text(source),
            rate,
            active_edge,
            sample_mode,
            samps_per_chan,
        )
    })
}

#[unsafe(no_mangle)]
pub extern "C" fn DAQmxCfgInputBuffer(task: TaskHandle, samps_per_chan: u32) -> i32 {
    status(|| sys().cfg_input_buffer(handle(task), samps_per_chan))
}

#[unsafe(no_mangle)]
pub extern "C" fn DAQmxSetReadOverWrite(task: TaskHandle, data: i32) -> i32 {
    status(|| sys().set_read_overwrite(handle(task), data))
}

#[unsafe(no_mangle)]
pub extern "C" fn DAQmxSetReadRelativeTo(task: TaskHandle, data: i32) -> i32 {
    status(|| sys().set_read_relative_to(handle(task), data))
}

#[unsafe(no_mangle)]
pub extern "C" fn DAQmxSetReadOffset(task: TaskHandle, data: i32) -> i32 {
    status(|| sys().set_read_offset(handle(task), data))
}

#[unsafe(no_mangle)]
pub extern "C" fn DAQmxStartTask(task: TaskHandle) -> i32 {
    status(|| sys().start_task(handle(task)))
}

#[unsafe(no_mangle)]
pub extern "C" fn DAQmxStopTask(task: TaskHandle) -> i32 {
    status(|| sys().stop_task(handle(task)))
}

#[unsafe(no_mangle)]
pub extern "C" fn DAQmxClearTask(task: TaskHandle) -> i32 {
    status(|| sys().clear_task(handle(task)))
}

/// # Safety
/// `read_array` holds `array_size_in_samps` doubles; `samps_per_chan_read` is NULL or writable.
#[allow(clippy::too_many_arguments)]
#[unsafe(no_mangle)]
pub unsafe extern "C" fn DAQmxReadAnalogF64(
    task: TaskHandle,
    num_samps_per_chan: i32,
    timeout: f64,
    fill_mode: u32,
    read_array: *mut f64,
    array_size_in_samps: u32,
    samps_per_chan_read: *mut i32,
    _reserved: *mut u32,
) -> i32 {
    let mut read = 0usize;
    let st = status(|| {
        let out: &mut [f64] = if read_array.is_null() {
            &mut []
        } else {
            // SAFETY: the caller's array holds `array_size_in_samps` doubles.
            unsafe { std::slice::from_raw_parts_mut(read_array, array_size_in_samps as usize) }
        };
        let o = sys().read_analog_f64(handle(task), num_samps_per_chan, timeout, fill_mode, out);
        read = o.read;
        o.error.map_or(Ok(()), Err)
    });
    if !samps_per_chan_read.is_null() {
        // SAFETY: the caller passes a writable int32.
        unsafe { *samps_per_chan_read = i32::try_from(read).unwrap_or(i32::MAX) };
    }
    st
}

/// # Safety
/// `data` is writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn DAQmxGetReadTotalSampPerChanAcquired(
    task: TaskHandle,
    data: *mut u64,
) -> i32 {
    status(|| {
        let n = sys().total_acquired(handle(task))?;
        if !data.is_null() {
            // SAFETY: the caller passes a writable uInt64.
            unsafe { *data = n };
        }
        Ok(())
    })
}

/// # Safety
/// `buf` holds `size` bytes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn DAQmxGetExtendedErrorInfo(buf: *mut c_char, size: u32) -> i32 {
    copy_out(&errors::last_error(), buf, size)
}

/// # Safety
/// `buf` holds `size` bytes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn DAQmxGetErrorString(code: i32, buf: *mut c_char, size: u32) -> i32 {
    copy_out(errors::describe(code), buf, size)
}

/// # Safety
/// `device` is a C string; `hook` is NULL or points to a valid [`StandinHook`] whose callbacks
/// stay callable from any thread until [`standin_detach`] returns.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn standin_attach(device: *const c_char, hook: *const StandinHook) -> i32 {
    // SAFETY: the caller passes NULL or a valid hook.
    let hook = (!hook.is_null()).then(|| unsafe { *hook });
    status(|| sys().attach(&text(device), hook))
}

/// # Safety
/// `device` is a C string.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn standin_detach(device: *const c_char) -> i32 {
    status(|| sys().detach(&text(device)))
}

/// # Safety
/// `device` is a C string.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn standin_inject(
    device: *const c_char,
    fault: u32,
    at_sample: u64,
    arg: u64,
) -> i32 {
    status(|| sys().inject(&text(device), fault, at_sample, arg))
}

/// # Safety
/// `device` is a C string.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn standin_log(device: *const c_char, max_samples: u64) -> i32 {
    status(|| sys().set_log(&text(device), max_samples))
}

/// Copies logged samples `first..first + n` (`LOG_WIDTH` doubles each) into `out`; returns how
/// many samples were copied.
///
/// # Safety
/// `device` is a C string; `out` holds `n * LOG_WIDTH` doubles.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn standin_log_read(
    device: *const c_char,
    first: u64,
    n: u64,
    out: *mut f64,
) -> u64 {
    let rows = catch_unwind(AssertUnwindSafe(|| sys().log_read(&text(device), first, n)))
        .unwrap_or_default();
    if out.is_null() {
        return 0;
    }
    for (i, row) in rows.iter().enumerate() {
        // SAFETY: `out` holds n * LOG_WIDTH doubles and rows.len() <= n.
        unsafe {
            std::ptr::copy_nonoverlapping(row.as_ptr(), out.add(i * LOG_WIDTH), LOG_WIDTH);
        }
    }
    rows.len() as u64
}

/// # Safety
/// `device` is a C string; `out` is writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn standin_stats(device: *const c_char, out: *mut StandinStats) -> i32 {
    status(|| {
        let s = sys().stats(&text(device))?;
        if !out.is_null() {
            // SAFETY: the caller passes a writable StandinStats.
            unsafe { *out = s };
        }
        Ok(())
    })
}
