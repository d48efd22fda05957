//! The F/T and camera streams of a run, each read on its own task for the whole run.
//!
//! - The **F/T stream** is read by the safety supervisor ([`super::safety`]), which checks
//!   every [`WrenchSample`](crate::force::WrenchSample) against the force limit (tared
//!   samples only, unless the config asks for no tare: an untared reading is mostly the
//!   sensor's bias) and saturation, watches both streams for stalls, beats the controller's
//!   watchdog and commands the stop first on a [`Trip`]. It hands samples on to the recording
//!   without ever waiting for it.
//! - The **camera task** reads every frame of the [`FrameSource`], stamps its arrival for the
//!   supervisor's stall check, and hands it to the **encoder thread**, which readies it for the
//!   file off the async workers ([`stored_image`]: an MJPEG camera's JPEG as sent, raw pixels
//!   as lossless PNG) and forwards it. The stream ending raises a [`Trip`].
//!
//! Both end in one bounded channel (the collector's input). When it is full the F/T forwarder
//! and the encoder wait: a slow consumer shows as back-pressure (counted in
//! [`StreamCounters::backpressure_waits`], warned about once). The reading tasks never wait:
//! when their own queue toward the recording is full, the item is lost for the recording
//! (counted in [`StreamCounters::recording_lost`]) and the trajectory fails with a recording
//! error, never silently.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use rig_core::clock::Clock;
use tokio::sync::{mpsc, watch};
use tokio::task::JoinHandle;

use super::events::{EncodedFrame, Event, StreamCounters, StreamSettings, Trip, note_backpressure};
use super::safety::{self, SafetyIo, SafetyStop};
use crate::camera::{CameraError, Frame, FrameSource, PixelFormat};
use crate::force::{FtStream, TareHandle, TareReport};
use crate::record::ImageFormat;

/// Frames queued toward the encoder thread before they are lost for the recording (about 2 s at
/// 30 fps, for an encoder held up by back-pressure).
const ENCODER_QUEUE: usize = 64;

/// The running streams.
pub struct Streams {
    shared: Arc<safety::Shared>,
    trips_in: mpsc::UnboundedSender<Trip>,
    /// `None` without an F/T sensor.
    tare: Option<TareHandle>,
    tasks: Vec<JoinHandle<()>>,
    encoder: Option<std::thread::JoinHandle<()>>,
    stop: Arc<AtomicBool>,
}

/// Freezes or thaws a run's safety supervisor (see [`Streams::freeze_handle`]).
#[derive(Clone)]
pub struct SupervisorFreeze(Arc<safety::Shared>);

impl SupervisorFreeze {
    pub fn freeze(&self, frozen: bool) {
        if frozen {
            tracing::warn!("freezing the safety supervisor (drill)");
        }
        self.0.frozen.send_replace(frozen);
    }
}

impl Streams {
    /// Starts the supervisor on `ft` (none: no F/T sensor, forces are watched on the flange,
    /// `settings.flange`) and the camera task on `camera`. Events go to `out` (the collector's
    /// input). With `safety`, the supervisor owns the robot's heartbeat and stop.
    pub fn start(
        ft: Option<FtStream>,
        camera: Option<Box<dyn FrameSource>>,
        clock: Clock,
        settings: StreamSettings,
        out: mpsc::Sender<Event>,
        safety: Option<SafetyIo>,
        observer: Option<safety::StopObserver>,
    ) -> Self {
        let (trip_tx, _) = watch::channel(None);
        let counters = Arc::new(StreamCounters::default());
        let shared = Arc::new(safety::Shared {
            trip_tx: Arc::new(trip_tx),
            counters: counters.clone(),
            stops: std::sync::Mutex::new(Vec::new()),
            extent: std::sync::Mutex::new(None),
            observer,
            last_state: std::sync::Mutex::new(None),
            last_beat_ns: AtomicU64::new(if safety.is_some() {
                clock.now_ns()
            } else {
                u64::MAX
            }),
            frozen: watch::channel(false).0,
        });
        let stop = Arc::new(AtomicBool::new(false));
        let tare = ft.as_ref().map(FtStream::tare_handle);
        let (trips_in, trips_rx) = mpsc::unbounded_channel();
        let mut tasks: Vec<JoinHandle<()>> = safety::spawn(
            ft,
            clock.clone(),
            settings,
            camera.is_some(),
            shared.clone(),
            safety,
            trips_rx,
            out.clone(),
        )
        .into();
        let mut encoder = None;
        if let Some(cam) = camera {
            let (enc_tx, enc_rx) = mpsc::channel::<Frame>(ENCODER_QUEUE);
            let (c, o, s) = (counters.clone(), out.clone(), stop.clone());
            encoder = std::thread::Builder::new()
                .name("frame-encoder".into())
                .spawn(move || encoder_thread(enc_rx, o, c, s))
                .map_err(|e| tracing::error!("cannot start the frame encoder thread: {e}"))
                .ok();
            tasks.push(tokio::spawn(camera_task(
                cam,
                clock,
                enc_tx,
                trips_in.clone(),
                counters.clone(),
            )));
        }
        Self {
            shared,
            trips_in,
            tare,
            tasks,
            encoder,
            stop,
        }
    }

    /// Watch the trips.
    pub fn trips(&self) -> watch::Receiver<Option<Trip>> {
        self.shared.trip_tx.subscribe()
    }

    /// The current trip, if any.
    pub fn current_trip(&self) -> Option<Trip> {
        self.shared.trip_tx.borrow().clone()
    }

    /// Clears a non-fatal trip (after the robot retracted); a fatal one stays and is returned.
    pub fn clear_trip(&self) -> Option<Trip> {
        self.shared.trip_tx.send_if_modified(|cur| {
            if cur.as_ref().is_some_and(|t| !t.is_fatal()) {
                *cur = None;
                true
            } else {
                false
            }
        });
        self.current_trip()
    }

    /// Raises a trip from outside (tests, the orchestrator): the supervisor stops the arm
    /// first, then publishes it.
    pub fn trip(&self, t: Trip) {
        let _ = self.trips_in.send(t);
    }

    /// The box the reported TCP positions stayed in, m (`None`: no state seen).
    pub fn tcp_extent(&self) -> Option<[[f64; 3]; 2]> {
        *self.shared.extent.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Every stop the supervisor commanded so far.
    pub fn safety_stops(&self) -> Vec<SafetyStop> {
        self.shared
            .stops
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
    }

    /// A handle that freezes the supervisor (a drill: no checks, no heartbeat, as a hung
    /// task), or thaws it.
    pub fn freeze_handle(&self) -> SupervisorFreeze {
        SupervisorFreeze(self.shared.clone())
    }

    /// Whether the supervisor still feeds the controller's watchdog: a heartbeat written
    /// after now, within `timeout` of clock time (at once without a safety line: nothing to
    /// feed). A healthy supervisor beats on every RTDE state (2 ms on an e-Series).
    pub async fn supervisor_responds(&self, clock: &Clock, timeout: Duration) -> bool {
        let t0 = clock.now_ns();
        let beat = || self.shared.last_beat_ns.load(Ordering::Acquire);
        if beat() == u64::MAX {
            return true;
        }
        let deadline = t0.saturating_add(u64::try_from(timeout.as_nanos()).unwrap_or(u64::MAX));
        while clock.now_ns() < deadline {
            if beat() > t0 {
                return true;
            }
            clock.sleep(Duration::from_millis(5)).await;
        }
        beat() > t0
    }

    pub fn counters(&self) -> &Arc<StreamCounters> {
        &self.shared.counters
    }

    /// Applies the force limit to untared samples too (the config asks for no tare).
    pub fn arm_force_limit(&self) {
        self.shared
            .counters
            .force_limit_untared
            .store(true, Ordering::Release);
    }

    /// Tare the F/T over the next `samples` samples (the indenter must be off the gel).
    pub async fn tare(&self, samples: u64) -> Result<TareReport, crate::force::FtError> {
        match &self.tare {
            Some(t) => t.tare(samples).await,
            None => Err(crate::force::FtError::Config(
                "the config has no [force_sensor]: there is no F/T sensor to tare".into(),
            )),
        }
    }

    /// Stops every task and the encoder.
    pub async fn shutdown(mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.tasks.drain(..) {
            t.abort();
            let _ = t.await;
        }
        if let Some(e) = self.encoder.take() {
            // The encoder ends once the camera task (its sender) is gone.
            let _ = tokio::task::spawn_blocking(move || e.join()).await;
        }
    }
}

impl Drop for Streams {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in &self.tasks {
            t.abort();
        }
    }
}

/// Reads frames and queues them for the encoder without ever waiting: the supervisor's stall
/// check reads the arrival stamps, so this task must keep reading whatever the recording does.
async fn camera_task(
    mut cam: Box<dyn FrameSource>,
    clock: Clock,
    enc: mpsc::Sender<Frame>,
    trips: mpsc::UnboundedSender<Trip>,
    counters: Arc<StreamCounters>,
) {
    loop {
        let frame = match cam.next_frame().await {
            Ok(f) => f,
            Err(CameraError::BadFrame(why)) => {
                tracing::warn!("camera: bad frame skipped: {why}");
                counters.frames_unencodable.fetch_add(1, Ordering::Relaxed);
                continue;
            }
            Err(e) => {
                let _ = trips.send(Trip::CameraLost(e.to_string()));
                return;
            }
        };
        counters
            .last_frame_rx_ns
            .fetch_max(clock.now_ns(), Ordering::AcqRel);
        counters.frames.fetch_add(1, Ordering::Relaxed);
        counters
            .frames_dropped
            .fetch_add(frame.dropped_before, Ordering::Relaxed);
        match enc.try_send(frame) {
            Ok(()) => {}
            Err(mpsc::error::TrySendError::Full(_)) => counters.note_recording_lost(),
            Err(mpsc::error::TrySendError::Closed(_)) => return,
        }
    }
}

/// What a frame is recorded as: camera bytes as received where they are already an image
/// file — an MJPEG camera's JPEG, untouched (checked for its markers and size, not decoded:
/// [`Frame::check_jpeg`]) — and lossless PNG for raw pixels (RGB, YUYV; the simulated camera
/// with `[camera] format = "raw"`).
pub fn stored_image(frame: &Frame) -> Result<(ImageFormat, Vec<u8>), String> {
    if frame.format.pixel == PixelFormat::Mjpeg {
        frame.check_jpeg().map_err(|e| e.to_string())?;
        return Ok((ImageFormat::Jpeg, frame.data.clone()));
    }
    let img = frame
        .to_rgb()
        .map_err(|e| format!("cannot convert to RGB: {e}"))?;
    let png = crate::record::png::encode(&img).map_err(|e| format!("PNG encoding failed: {e}"))?;
    Ok((ImageFormat::Png, png))
}

fn encoder_thread(
    mut rx: mpsc::Receiver<Frame>,
    out: mpsc::Sender<Event>,
    counters: Arc<StreamCounters>,
    stop: Arc<AtomicBool>,
) {
    while let Some(frame) = rx.blocking_recv() {
        if stop.load(Ordering::Relaxed) {
            return;
        }
        let (format, data) = match stored_image(&frame) {
            Ok(img) => img,
            Err(e) => {
                tracing::warn!("frame {}: {e}", frame.sequence);
                counters.frames_unencodable.fetch_add(1, Ordering::Relaxed);
                continue;
            }
        };
        counters
            .stored_frame_bytes
            .fetch_add(data.len() as u64, Ordering::Relaxed);
        counters.stored_frames.fetch_add(1, Ordering::Release);
        let stamp_ns = frame.capture_t_ns.unwrap_or(frame.device_ts_ns);
        let ev = Event::Frame(Box::new(EncodedFrame {
            seq: frame.sequence,
            stamp_ns,
            host_rx_ns: frame.received_t_ns,
            dropped_before: frame.dropped_before,
            format,
            data,
            truth: frame.truth.map(|t| (t.capture_t_ns, t.wrench)),
        }));
        let sent = match out.try_send(ev) {
            Ok(()) => true,
            Err(mpsc::error::TrySendError::Full(ev)) => {
                note_backpressure(&counters);
                out.blocking_send(ev).is_ok()
            }
            Err(mpsc::error::TrySendError::Closed(_)) => false,
        };
        if !sent {
            return;
        }
        counters
            .newest_frame_stamp_ns
            .fetch_max(stamp_ns, Ordering::Relaxed);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::force::WrenchSample;
    use rig_core::ft::SampleFlags;
    use rig_core::wrench::Wrench;

    fn sample(seq: u64, fz: f64, flags: SampleFlags) -> WrenchSample {
        WrenchSample {
            t_host_ns: seq * 1_000_000,
            device_seq: seq,
            wrench: Wrench {
                force_n: [0.0, 0.0, fz],
                torque_nmm: [0.0; 3],
            },
            status: 0,
            flags,
        }
    }

    /// Feeds `samples` through the F/T task (arming the untared limit first if asked) and
    /// returns the trip they raised, once all were forwarded.
    async fn run(samples: &[WrenchSample], untared_limit: bool) -> Option<Trip> {
        let (ft, sink, _ctl, _done) = FtStream::channel("test".into());
        let (out_tx, mut out_rx) = mpsc::channel(64);
        let streams = Streams::start(
            Some(ft),
            None,
            Clock::system(),
            StreamSettings {
                max_force_n: 1.0,
                ft_stall: Duration::from_secs(60),
                camera_stall: Duration::from_secs(60),
                envelope: None,
                flange: None,
            },
            out_tx,
            None,
            None,
        );
        if untared_limit {
            streams.arm_force_limit();
        }
        for s in samples {
            sink.deliver(*s);
        }
        for _ in samples {
            out_rx.recv().await.unwrap();
        }
        let t = streams.current_trip();
        streams.shutdown().await;
        t
    }

    #[tokio::test]
    async fn untared_samples_queued_before_the_tare_do_not_trip_the_force_limit() {
        // The sensor's bias (3 N) in samples read before the tare took effect, however late
        // the task gets to them; then tared contact forces under and over the 1 N limit.
        let untared = sample(1, -3.0, SampleFlags::UNTARED);
        let under = sample(2, -0.9, SampleFlags::NONE);
        let over = sample(3, -1.5, SampleFlags::NONE);
        assert_eq!(run(&[untared, under], false).await, None);
        match run(&[untared, under, over], false).await {
            Some(Trip::ForceLimit { force_n, limit_n }) => {
                assert!((force_n - 1.5).abs() < 1e-12 && limit_n == 1.0);
            }
            t => panic!("expected the tared 1.5 N sample to trip, got {t:?}"),
        }
        // No tare configured: the readings are taken as they are, limit included.
        match run(&[untared], true).await {
            Some(Trip::ForceLimit { force_n, .. }) => assert!((force_n - 3.0).abs() < 1e-12),
            t => panic!("expected the untared 3 N sample to trip, got {t:?}"),
        }
    }
}
