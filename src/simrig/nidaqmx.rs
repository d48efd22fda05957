//! The simulated Nano17 on a simulated NI card (`rig run --sim-ft nidaqmx`): the stand-in
//! NI-DAQmx library (`nidaqmx-standin`) is loaded with the same `dlopen` path the lab rig uses
//! for NI's own, handed the simulated rig's clock, true wrench and faults through its one extra
//! symbol (`standin_attach`), and read by the lab's NI reader.

use std::ffi::{CString, c_char, c_void};
use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use anyhow::Context;
use hardware_mocks::nano17::Faults;
use hardware_mocks::nano17::nidaqmx::hook::{
    FAULT_BIT_OVERLOAD, FAULT_BIT_REMOVED, HOOK_VERSION, StandinHook,
};
use hardware_mocks::truth::SharedWrenchSource;
use rig_core::clock::{Clock, Pacer, SIM_PACER_LEAD};
use rig_core::config::ForceSensorConfig;
use rig_core::ft::nidaqmx::DEFAULT_CHANNELS;
use rig_core::ft::transform::ToolTransform;

use crate::force::nidaqmx::{self, Api, LIBRARY_ENV, library};
use crate::force::{FrontEndSettings, FtStream};

/// The stand-in's file name as cargo builds it.
pub const STANDIN_FILE: &str = "libnidaqmx_standin.so";
/// The simulated card's device name.
pub const DEVICE: &str = "Dev1";

/// Where the stand-in is: `RIG_NIDAQMX_LIBRARY`, else beside the rig's executable.
pub fn standin_path() -> anyhow::Result<PathBuf> {
    if let Some(p) = std::env::var_os(LIBRARY_ENV).filter(|v| !v.is_empty()) {
        return Ok(PathBuf::from(p));
    }
    library::beside_executable(STANDIN_FILE).with_context(|| {
        format!(
            "--sim-ft nidaqmx needs the stand-in NI-DAQmx library {STANDIN_FILE}, and it is not \
             beside the rig executable: build it with `cargo build -p nidaqmx-standin` (same \
             profile as the rig), or set {LIBRARY_ENV} to its path"
        )
    })
}

/// What the stand-in's callbacks read: the simulated rig's clock, its true wrench at the tool
/// point (moved to the sensor frame here) and its F/T faults. While the card acquires, its
/// reader polls the clock as it waits for samples; each poll reports to a pacer of the simulated
/// clock, so a host that stalls the reader thread holds simulated time instead of letting the
/// card overwrite its buffer (as every simulated device does). A card that stops acquiring (the
/// stream ended, the card removed) drops its pacer, so the rest of the rig runs on.
struct HookCtx {
    clock: Clock,
    pacer: Mutex<Option<Pacer>>,
    source: SharedWrenchSource,
    tool: ToolTransform,
    faults: Arc<Faults>,
}

unsafe extern "C" fn now_ns(ctx: *mut c_void) -> u64 {
    // SAFETY: `ctx` is the `HookCtx` the guard owns until after detaching.
    let ctx = unsafe { &*ctx.cast::<HookCtx>() };
    let now = ctx.clock.now_ns();
    if let Some(p) = ctx.pacer.lock().unwrap_or_else(|e| e.into_inner()).as_ref() {
        p.reached(now);
    }
    now
}

unsafe extern "C" fn acquiring(ctx: *mut c_void, on: u32) {
    // SAFETY: as in `now_ns`.
    let ctx = unsafe { &*ctx.cast::<HookCtx>() };
    *ctx.pacer.lock().unwrap_or_else(|e| e.into_inner()) = (on != 0).then(|| {
        ctx.clock
            .pacer("simulated NI card's reader", SIM_PACER_LEAD)
    });
}

unsafe extern "C" fn wrench_at(ctx: *mut c_void, t_ns: u64, out: *mut f64) {
    // SAFETY: as in `now_ns`; `out` has room for six values.
    let ctx = unsafe { &*ctx.cast::<HookCtx>() };
    let w = ctx.tool.invert(&ctx.source.wrench_at(t_ns).to_array());
    unsafe { std::ptr::copy_nonoverlapping(w.as_ptr(), out, 6) };
}

unsafe extern "C" fn faults(ctx: *mut c_void) -> u32 {
    // SAFETY: as in `now_ns`.
    let ctx = unsafe { &*ctx.cast::<HookCtx>() };
    let mut bits = 0;
    if ctx.faults.unplugged() {
        bits |= FAULT_BIT_REMOVED;
    }
    if ctx.faults.saturated() {
        bits |= FAULT_BIT_OVERLOAD;
    }
    bits
}

type AttachFn = unsafe extern "C" fn(*const c_char, *const StandinHook) -> i32;
type DetachFn = unsafe extern "C" fn(*const c_char) -> i32;

/// Keeps the hook attached; detaches it (no callback runs after that) before freeing it.
struct Attached {
    detach: DetachFn,
    device: CString,
    ctx: *mut HookCtx,
}

// The context is only read, from whichever thread the stand-in calls back on.
unsafe impl Send for Attached {}

impl Drop for Attached {
    fn drop(&mut self) {
        // SAFETY: a C string; after detach returns no callback uses `ctx`.
        unsafe { (self.detach)(self.device.as_ptr()) };
        drop(unsafe { Box::from_raw(self.ctx) });
    }
}

fn attach(api: &Api, ctx: HookCtx) -> anyhow::Result<Attached> {
    let lib = api.library();
    // SAFETY: the stand-in's own C signatures (see hardware_mocks::nano17::nidaqmx::hook).
    let (attach, detach) = unsafe {
        (
            *lib.get::<AttachFn>(b"standin_attach")
                .with_context(|| format!("{} is not the NI-DAQmx stand-in", api.origin))?,
            *lib.get::<DetachFn>(b"standin_detach")
                .with_context(|| format!("{} is not the NI-DAQmx stand-in", api.origin))?,
        )
    };
    let device = CString::new(DEVICE).expect("no NUL in the device name");
    let ctx = Box::into_raw(Box::new(ctx));
    let hook = StandinHook {
        version: HOOK_VERSION,
        ctx: ctx.cast(),
        now_ns: Some(now_ns),
        wrench_at: Some(wrench_at),
        faults: Some(faults),
        acquiring: Some(acquiring),
    };
    let guard = Attached {
        detach,
        device,
        ctx,
    };
    // SAFETY: the hook's callbacks stay valid until the guard detaches them.
    let st = unsafe { attach(guard.device.as_ptr(), &hook) };
    anyhow::ensure!(st == 0, "standin_attach failed with status {st}");
    Ok(guard)
}

/// Loads the stand-in, attaches the simulated rig to its `Dev1` and opens it with the lab's NI
/// reader (gauges on `Dev1/ai0:5`, the thermistor on `Dev1/ai6`, differential).
pub async fn open(
    fs: &ForceSensorConfig,
    settings: &mut FrontEndSettings,
    source: SharedWrenchSource,
    faults: Arc<Faults>,
    clock: Clock,
) -> anyhow::Result<FtStream> {
    let path = standin_path()?;
    let api = library::load_path(&path, "the simulated rig")?;
    // The simulated Nano17's calibration is the one the stand-in's sensor model inverts.
    settings
        .calibration
        .get_or_insert_with(hardware_mocks::nano17::sim_calibration);
    let cfg = ForceSensorConfig {
        channels: Some(DEFAULT_CHANNELS.to_owned()),
        thermistor_channel: None,
        ..fs.clone()
    };
    let spec = nidaqmx::task_spec(&cfg, settings)?;
    let guard = attach(
        api,
        HookCtx {
            clock: clock.clone(),
            pacer: Mutex::new(None),
            source,
            tool: settings.tool.clone(),
            faults,
        },
    )?;
    let mut stream = nidaqmx::open_with(api, spec, settings.clone(), clock).await?;
    stream.description = format!("simulated Nano17 on an NI card ({})", stream.description);
    stream.keep_alive(Box::new(guard));
    Ok(stream)
}
