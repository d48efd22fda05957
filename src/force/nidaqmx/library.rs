//! NI-DAQmx's C library, loaded at run time with `dlopen` (the `libloading` crate), so the rig
//! builds and runs without NI's driver and only this front end needs it.
//!
//! Where it is looked for, in order: `force_sensor.library`, the environment variable
//! [`LIBRARY_ENV`], then the system's library search by soname, `libnidaqmx.so.1` and
//! `libnidaqmx.so` (the dynamic linker's own search: `LD_LIBRARY_PATH`, the `ld.so` cache,
//! `/usr/lib/x86_64-linux-gnu` and the other default directories, which is where NI's
//! package installs it and where NI's Python package finds it). A missing library is an error
//! that names what to install. A library that lacks one of the functions the reader calls is
//! refused with the function's name.
//!
//! A loaded library stays loaded for the life of the process (NI's driver is not meant to be
//! unloaded, and a task's thread may still be inside it while a stream shuts down).

use std::collections::HashMap;
use std::ffi::{CString, c_char, c_void};
use std::path::{Path, PathBuf};
use std::sync::{Mutex, OnceLock};

use rig_core::ft::nidaqmx;

use crate::force::error::FtError;

/// The environment variable naming the NI-DAQmx library to load.
pub const LIBRARY_ENV: &str = "RIG_NIDAQMX_LIBRARY";
/// The sonames the system search tries, in order.
pub const SONAMES: [&str; 2] = ["libnidaqmx.so.1", "libnidaqmx.so"];
/// What to install when no library is found.
pub const INSTALL_HINT: &str = "install NI-DAQmx for Linux (NI's `ni-daqmx` package, from NI's \
     Linux device-driver repository for your distribution; it installs libnidaqmx.so.1 and the \
     card's kernel driver), or set force_sensor.library or RIG_NIDAQMX_LIBRARY to the path of \
     libnidaqmx.so";

/// NI's `TaskHandle`.
pub type TaskHandle = *mut c_void;

/// A task handle that [`Api::create_task`] made: the only handles the other calls take.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Handle(TaskHandle);

// An opaque token of NI's library, usable from any thread (one at a time, as the reader does).
unsafe impl Send for Handle {}

type CreateTask = unsafe extern "C" fn(*const c_char, *mut TaskHandle) -> i32;
type CreateAiVoltageChan = unsafe extern "C" fn(
    TaskHandle,
    *const c_char,
    *const c_char,
    i32,
    f64,
    f64,
    i32,
    *const c_char,
) -> i32;
type CfgSampClkTiming = unsafe extern "C" fn(TaskHandle, *const c_char, f64, i32, i32, u64) -> i32;
type CfgInputBuffer = unsafe extern "C" fn(TaskHandle, u32) -> i32;
type SetI32 = unsafe extern "C" fn(TaskHandle, i32) -> i32;
type TaskCall = unsafe extern "C" fn(TaskHandle) -> i32;
type ReadAnalogF64 =
    unsafe extern "C" fn(TaskHandle, i32, f64, u32, *mut f64, u32, *mut i32, *mut u32) -> i32;
type GetU64 = unsafe extern "C" fn(TaskHandle, *mut u64) -> i32;
type GetExtendedErrorInfo = unsafe extern "C" fn(*mut c_char, u32) -> i32;
type GetErrorString = unsafe extern "C" fn(i32, *mut c_char, u32) -> i32;

/// The functions of NI-DAQmx the reader calls, resolved from one loaded library.
pub struct Api {
    /// What was loaded: the path, or the soname the system search resolved.
    pub origin: String,
    lib: libloading::Library,
    create_task: CreateTask,
    create_ai_voltage_chan: CreateAiVoltageChan,
    cfg_samp_clk_timing: CfgSampClkTiming,
    cfg_input_buffer: CfgInputBuffer,
    set_read_overwrite: SetI32,
    set_read_offset: SetI32,
    start_task: TaskCall,
    stop_task: TaskCall,
    clear_task: TaskCall,
    read_analog_f64: ReadAnalogF64,
    get_read_total_samp_per_chan_acquired: GetU64,
    get_extended_error_info: GetExtendedErrorInfo,
    get_error_string: GetErrorString,
}

impl std::fmt::Debug for Api {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "NI-DAQmx ({})", self.origin)
    }
}

/// Loads the library a `[force_sensor]` section names (`library`), else the one
/// [`LIBRARY_ENV`] names, else the system's.
pub fn load(configured: Option<&Path>) -> Result<&'static Api, FtError> {
    if let Some(p) = configured {
        return load_path(p, "force_sensor.library");
    }
    if let Some(p) = std::env::var_os(LIBRARY_ENV).filter(|v| !v.is_empty()) {
        return load_path(Path::new(&p), LIBRARY_ENV);
    }
    let mut tried = Vec::new();
    for name in SONAMES {
        match open_cached(name) {
            Ok(api) => return Ok(api),
            Err(Open::Missing(reason)) => tried.push(format!("{name} ({reason})")),
            Err(Open::Refused(e)) => return Err(e),
        }
    }
    Err(FtError::NiLibrary(format!(
        "force_sensor.kind = \"nidaqmx\" needs NI's NI-DAQmx library, and the system's library \
         search did not find it (tried {}): {INSTALL_HINT}",
        tried.join("; ")
    )))
}

/// Loads the library at `path` (`what` says where the path came from, for the message).
pub fn load_path(path: &Path, what: &str) -> Result<&'static Api, FtError> {
    match open_cached(&path.to_string_lossy()) {
        Ok(api) => Ok(api),
        Err(Open::Refused(e)) => Err(e),
        Err(Open::Missing(reason)) => Err(FtError::NiLibrary(format!(
            "cannot load the NI-DAQmx library {} (from {what}): {reason}; {INSTALL_HINT}",
            path.display()
        ))),
    }
}

enum Open {
    /// Not found or not loadable: try the next candidate.
    Missing(String),
    /// Loaded, but not an NI-DAQmx library.
    Refused(FtError),
}

/// One `dlopen` per name for the process; the library is never unloaded.
fn open_cached(name: &str) -> Result<&'static Api, Open> {
    static LOADED: OnceLock<Mutex<HashMap<String, &'static Api>>> = OnceLock::new();
    let mut loaded = LOADED
        .get_or_init(Default::default)
        .lock()
        .unwrap_or_else(|p| p.into_inner());
    if let Some(api) = loaded.get(name) {
        return Ok(api);
    }
    // SAFETY: loading a shared library runs its initialisers; NI's library (or a stand-in with
    // its symbols) is what the operator pointed the rig at.
    let lib =
        unsafe { libloading::Library::new(name) }.map_err(|e| Open::Missing(e.to_string()))?;
    let api: &'static Api = Box::leak(Box::new(Api::resolve(name, lib).map_err(Open::Refused)?));
    loaded.insert(name.to_owned(), api);
    Ok(api)
}

/// The path of a shared library next to the running executable, where cargo puts the
/// workspace's own libraries (`target/<profile>/` and its `deps/`), if one is there.
pub fn beside_executable(file_name: &str) -> Option<PathBuf> {
    let exe = std::env::current_exe().ok()?;
    let dir = exe.parent()?;
    [
        dir.join(file_name),
        dir.join("deps").join(file_name),
        dir.parent()?.join(file_name),
    ]
    .into_iter()
    .find(|p| p.is_file())
}

impl Api {
    fn resolve(origin: &str, lib: libloading::Library) -> Result<Self, FtError> {
        fn sym<T: Copy>(lib: &libloading::Library, origin: &str, name: &str) -> Result<T, FtError> {
            // SAFETY: the type is the function's C signature from NIDAQmx.h.
            unsafe { lib.get::<T>(name.as_bytes()) }
                .map(|s| *s)
                .map_err(|_| {
                    FtError::NiLibrary(format!(
                        "{origin} is not an NI-DAQmx library: it has no function {name}; {INSTALL_HINT}"
                    ))
                })
        }
        Ok(Self {
            create_task: sym(&lib, origin, "DAQmxCreateTask")?,
            create_ai_voltage_chan: sym(&lib, origin, "DAQmxCreateAIVoltageChan")?,
            cfg_samp_clk_timing: sym(&lib, origin, "DAQmxCfgSampClkTiming")?,
            cfg_input_buffer: sym(&lib, origin, "DAQmxCfgInputBuffer")?,
            set_read_overwrite: sym(&lib, origin, "DAQmxSetReadOverWrite")?,
            set_read_offset: sym(&lib, origin, "DAQmxSetReadOffset")?,
            start_task: sym(&lib, origin, "DAQmxStartTask")?,
            stop_task: sym(&lib, origin, "DAQmxStopTask")?,
            clear_task: sym(&lib, origin, "DAQmxClearTask")?,
            read_analog_f64: sym(&lib, origin, "DAQmxReadAnalogF64")?,
            get_read_total_samp_per_chan_acquired: sym(
                &lib,
                origin,
                "DAQmxGetReadTotalSampPerChanAcquired",
            )?,
            get_extended_error_info: sym(&lib, origin, "DAQmxGetExtendedErrorInfo")?,
            get_error_string: sym(&lib, origin, "DAQmxGetErrorString")?,
            origin: origin.to_owned(),
            lib,
        })
    }

    /// The loaded library itself, for symbols beyond NI's (a stand-in's own).
    pub fn library(&self) -> &libloading::Library {
        &self.lib
    }

    /// NI's message for the last error on this thread (`DAQmxGetExtendedErrorInfo`), else the
    /// code's description (`DAQmxGetErrorString`).
    fn message(&self, code: i32) -> String {
        let read = |f: &dyn Fn(*mut c_char, u32) -> i32| -> Option<String> {
            // With a zero-sized buffer NI returns the size it needs.
            let need = f(std::ptr::null_mut(), 0);
            let size = u32::try_from(need).ok().filter(|n| *n > 1)?.min(1 << 16);
            let mut buf = vec![0u8; size as usize];
            f(buf.as_mut_ptr().cast(), size);
            let end = buf.iter().position(|b| *b == 0).unwrap_or(buf.len());
            let s = String::from_utf8_lossy(&buf[..end]).trim().to_owned();
            (!s.is_empty()).then_some(s)
        };
        // SAFETY: the buffers are as large as the size passed.
        let ext = read(&|b, n| unsafe { (self.get_extended_error_info)(b, n) });
        ext.or_else(|| read(&|b, n| unsafe { (self.get_error_string)(code, b, n) }))
            .map(|s| s.split_whitespace().collect::<Vec<_>>().join(" "))
            .unwrap_or_else(|| "(no message from the library)".to_owned())
    }

    /// An error for a failed `call` with NI's message and a hint for the common codes.
    pub fn error(&self, call: &str, code: i32) -> FtError {
        FtError::Ni {
            call: call.to_owned(),
            code,
            message: self.message(code),
            hint: nidaqmx::hint(code).map(str::to_owned),
        }
    }

    /// `Ok` for success or a warning, else [`Self::error`].
    fn check(&self, call: &str, status: i32) -> Result<(), FtError> {
        if status >= 0 {
            Ok(())
        } else {
            Err(self.error(call, status))
        }
    }

    pub fn create_task(&self, name: &str) -> Result<Handle, FtError> {
        let name = c_string(name)?;
        let mut task: TaskHandle = std::ptr::null_mut();
        // SAFETY: C string and a writable handle, as NIDAQmx.h declares.
        let st = unsafe { (self.create_task)(name.as_ptr(), &mut task) };
        self.check("DAQmxCreateTask", st).map(|()| Handle(task))
    }

    pub fn create_ai_voltage_chan(
        &self,
        task: Handle,
        physical: &str,
        terminal: i32,
        min_v: f64,
        max_v: f64,
    ) -> Result<(), FtError> {
        let phys = c_string(physical)?;
        let empty = c_string("")?;
        // SAFETY: C strings for the names, NULL for no custom scale.
        let st = unsafe {
            (self.create_ai_voltage_chan)(
                task.0,
                phys.as_ptr(),
                empty.as_ptr(),
                terminal,
                min_v,
                max_v,
                nidaqmx::val::VOLTS,
                std::ptr::null(),
            )
        };
        self.check(&format!("DAQmxCreateAIVoltageChan({physical})"), st)
    }

    pub fn cfg_samp_clk_timing(
        &self,
        task: Handle,
        rate_hz: f64,
        buffer: u64,
    ) -> Result<(), FtError> {
        // SAFETY: NULL source: the card's onboard clock.
        let st = unsafe {
            (self.cfg_samp_clk_timing)(
                task.0,
                std::ptr::null(),
                rate_hz,
                nidaqmx::val::RISING,
                nidaqmx::val::CONT_SAMPS,
                buffer,
            )
        };
        self.check("DAQmxCfgSampClkTiming", st)
    }

    pub fn cfg_input_buffer(&self, task: Handle, samples: u32) -> Result<(), FtError> {
        // SAFETY: plain values.
        let st = unsafe { (self.cfg_input_buffer)(task.0, samples) };
        self.check("DAQmxCfgInputBuffer", st)
    }

    pub fn set_read_overwrite(&self, task: Handle, mode: i32) -> Result<(), FtError> {
        // SAFETY: plain values.
        let st = unsafe { (self.set_read_overwrite)(task.0, mode) };
        self.check("DAQmxSetReadOverWrite", st)
    }

    pub fn set_read_offset(&self, task: Handle, offset: i32) -> Result<(), FtError> {
        // SAFETY: plain values.
        let st = unsafe { (self.set_read_offset)(task.0, offset) };
        self.check("DAQmxSetReadOffset", st)
    }

    pub fn start_task(&self, task: Handle) -> Result<(), FtError> {
        // SAFETY: a handle from DAQmxCreateTask.
        let st = unsafe { (self.start_task)(task.0) };
        self.check("DAQmxStartTask", st)
    }

    pub fn stop_task(&self, task: Handle) -> Result<(), FtError> {
        // SAFETY: a handle from DAQmxCreateTask.
        let st = unsafe { (self.stop_task)(task.0) };
        self.check("DAQmxStopTask", st)
    }

    /// Clears the task (stopping it first); errors are of no use here.
    pub fn clear_task(&self, task: Handle) {
        // SAFETY: a handle from DAQmxCreateTask, cleared once.
        let _ = unsafe { (self.clear_task)(task.0) };
    }

    /// `DAQmxReadAnalogF64`, interleaved by scan: returns the status and the samples per channel
    /// read (a read cut short by an error still returns what it read).
    pub fn read_analog_f64(
        &self,
        task: Handle,
        samples: i32,
        timeout_s: f64,
        out: &mut [f64],
    ) -> (i32, usize) {
        let mut read: i32 = 0;
        let size = u32::try_from(out.len()).unwrap_or(u32::MAX);
        // SAFETY: `out` holds `size` doubles; `read` is writable; reserved is NULL.
        let st = unsafe {
            (self.read_analog_f64)(
                task.0,
                samples,
                timeout_s,
                nidaqmx::val::GROUP_BY_SCAN_NUMBER,
                out.as_mut_ptr(),
                size,
                &mut read,
                std::ptr::null_mut(),
            )
        };
        (st, usize::try_from(read).unwrap_or(0))
    }

    pub fn total_acquired(&self, task: Handle) -> Result<u64, FtError> {
        let mut n = 0u64;
        // SAFETY: a writable uInt64.
        let st = unsafe { (self.get_read_total_samp_per_chan_acquired)(task.0, &mut n) };
        self.check("DAQmxGetReadTotalSampPerChanAcquired", st)
            .map(|()| n)
    }
}

fn c_string(s: &str) -> Result<CString, FtError> {
    CString::new(s).map_err(|_| FtError::Config(format!("{s:?} contains a NUL byte")))
}
