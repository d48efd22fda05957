//! `rig ft …`: the F/T sensor from the command line.
//!
//! ```text
//! rig ft calibration FILE [--json]       the 6×6 matrix, max loads, condition number
//! rig ft tare   --config FILE [--samples N]            bias and noise of the unloaded sensor
//! rig ft stream --config FILE [--seconds S] [--json]   live readout: rate, wrench, noise
//! rig ft check  --config FILE [--seconds S]            pass/fail: rate, loss, noise, saturation
//! ```
//!
//! `stream` and `check` tare first (the sensor must be unloaded when they start).

// Axis loops index several parallel arrays (names, values, limits) by axis number.
#![allow(clippy::needless_range_loop)]

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, bail};
use clap::{Args, Subcommand};
use rig_core::clock::Clock;
use rig_core::config::{ForceSensorKind, RigConfig};
use rig_core::ft::AXES;
use rig_core::ft::bias::BiasEstimator;
use rig_core::ft::cal::Calibration;
use serde::Serialize;

/// Arguments of `rig ft`.
#[derive(Debug, Args)]
pub struct FtArgs {
    #[command(subcommand)]
    pub command: FtCommand,
}

/// The `rig ft` subcommands.
#[derive(Debug, Subcommand)]
pub enum FtCommand {
    /// Print an ATI calibration file's matrix (rows Fx..Tz in N and N·mm per gauge volt), max
    /// loads and condition number.
    Calibration(CalibrationArgs),
    /// Tare the unloaded sensor and print the bias and noise.
    Tare(LiveArgs),
    /// Live readout (rate, wrench, noise) for an operator at the rig.
    Stream(LiveArgs),
    /// Check the sensor: rate, lost records, noise, saturation. Exit status 1 on failure.
    Check(LiveArgs),
}

#[derive(Debug, Args)]
pub struct CalibrationArgs {
    /// The `.cal` file.
    pub file: PathBuf,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct LiveArgs {
    /// Rig config (TOML) with a `[force_sensor]` section. Default: ./rig.toml if present, else the
    /// built-in simulated rig.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Samples averaged by the tare (default: force_sensor.tare_samples).
    #[arg(long)]
    pub samples: Option<u64>,
    /// How long to stream or check, seconds.
    #[arg(long, default_value_t = 3.0)]
    pub seconds: f64,
    /// JSON lines instead of text.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: &FtArgs) -> anyhow::Result<()> {
    match &args.command {
        FtCommand::Calibration(a) => calibration(a),
        FtCommand::Tare(a) => live(a, Mode::Tare),
        FtCommand::Stream(a) => live(a, Mode::Stream),
        FtCommand::Check(a) => live(a, Mode::Check),
    }
}

#[derive(Serialize)]
struct CalibrationReport<'a> {
    file: String,
    serial: &'a str,
    body_style: &'a str,
    part_number: &'a str,
    cal_date: &'a str,
    source: rig_core::ft::cal::MatrixSource,
    rows: [&'static str; 6],
    /// Rows Fx..Tz; N (forces) or N·mm (torques) per gauge volt.
    matrix: [[f64; 6]; 6],
    max_loads: [f64; 6],
    condition_number: f64,
    scaled_condition_number: f64,
    ill_conditioned: bool,
    derivation_mismatch: Option<f64>,
    temperature_compensation: bool,
}

fn calibration(a: &CalibrationArgs) -> anyhow::Result<()> {
    let cal = Calibration::load(&a.file)?;
    let mut matrix = [[0.0; 6]; 6];
    for (i, row) in matrix.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = cal.matrix[(i, j)];
        }
    }
    let c = cal.conditioning();
    let report = CalibrationReport {
        file: a.file.display().to_string(),
        serial: &cal.serial,
        body_style: &cal.body_style,
        part_number: &cal.part_number,
        cal_date: &cal.cal_date,
        source: cal.source,
        rows: AXES,
        matrix,
        max_loads: cal.max_loads,
        condition_number: c.condition_number,
        scaled_condition_number: c.scaled_condition_number,
        ill_conditioned: c.ill_conditioned,
        derivation_mismatch: cal.derivation_mismatch(),
        temperature_compensation: cal.temperature.is_some(),
    };
    if a.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(());
    }
    println!(
        "{} {} serial {} ({}), calibrated {}",
        cal.body_style,
        cal.part_number,
        cal.serial,
        a.file.display(),
        cal.cal_date
    );
    println!(
        "matrix from {}; file units {} / {}, shown in N and N·mm per gauge volt",
        match cal.source {
            rig_core::ft::cal::MatrixSource::UserAxis => "UserAxis rows",
            rig_core::ft::cal::MatrixSource::AxisBasicTransform => "Axis / scale + BasicTransform",
        },
        cal.file_force_units,
        cal.file_torque_units
    );
    println!(
        "{:>4} {:>11} {:>11} {:>11} {:>11} {:>11} {:>11}   {:>9}",
        "", "G0", "G1", "G2", "G3", "G4", "G5", "max"
    );
    for i in 0..6 {
        print!("{:>4}", AXES[i]);
        for v in matrix[i] {
            print!(" {v:>11.5}");
        }
        println!(
            "   {:>7.2} {}",
            cal.max_loads[i],
            if i < 3 { "N" } else { "N·mm" }
        );
    }
    println!(
        "condition number {:.2} (rows scaled by max load: {:.2}){}",
        c.condition_number,
        c.scaled_condition_number,
        if c.ill_conditioned {
            "  ILL-CONDITIONED: forces from this matrix amplify gauge noise; check the file"
        } else {
            ""
        }
    );
    if let Some(m) = cal.derivation_mismatch() {
        println!("UserAxis vs Axis/scale+BasicTransform: max relative difference {m:.2e}");
    }
    if cal.temperature.is_some() {
        println!("temperature compensation: available (BiasSlope, GainSlope, Thermistor)");
    }
    Ok(())
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Mode {
    Tare,
    Stream,
    Check,
}

fn live(a: &LiveArgs, mode: Mode) -> anyhow::Result<()> {
    let loaded = super::config::resolve_config(a.config.as_deref())?;
    let config: &RigConfig = &loaded.config;
    let Some(ft) = config.force_sensor.clone() else {
        bail!("{} has no [force_sensor] section", loaded.source);
    };
    if !(a.seconds.is_finite() && a.seconds > 0.0) {
        bail!("--seconds must be a positive number");
    }
    let samples = a.samples.unwrap_or(u64::from(ft.tare_samples));
    let rt = tokio::runtime::Runtime::new()?;
    rt.block_on(async move {
        let clock = Clock::system();
        let opened = if ft.kind == ForceSensorKind::Sim {
            match crate::force::FrontEndSettings::from_config(&ft) {
                Ok(settings) => crate::simrig::open_ft(settings, clock.clone()).await,
                Err(e) => Err(e),
            }
        } else {
            crate::force::open(&ft, clock.clone()).await
        };
        let mut stream =
            opened.with_context(|| format!("opening the F/T sensor of {}", loaded.source))?;
        eprintln!(
            "reading {} (keep the sensor unloaded for the tare)",
            stream.description
        );
        let tare = stream.tare(samples).await?;
        print_tare(&tare, a.json)?;
        if mode == Mode::Tare {
            stream.finish().await?;
            return Ok(());
        }
        // Drain what arrived during the tare.
        while stream.try_next().is_some() {}
        let start_stats = stream.stats();
        let t0 = clock.now_ns();
        let end = t0 + (a.seconds * 1e9) as u64;
        let mut window = BiasEstimator::new();
        let mut all = BiasEstimator::new();
        let mut win_start = t0;
        let mut win_n = 0u64;
        let mut flagged = 0u64;
        loop {
            let now_ns = clock.now_ns();
            if now_ns >= end {
                break;
            }
            let s = match clock
                .timeout(Duration::from_millis(500), stream.next())
                .await
            {
                Ok(Some(s)) => s,
                Ok(None) => break,
                Err(_) => continue,
            };
            let w = s.wrench.to_array();
            window.push(&w);
            all.push(&w);
            win_n += 1;
            if !s.flags.is_clean() {
                flagged += 1;
            }
            let now_ns = clock.now_ns();
            if mode == Mode::Stream && now_ns - win_start >= 500_000_000 {
                let rate = win_n as f64 / ((now_ns - win_start) as f64 * 1e-9);
                if let Some(e) = window.estimate() {
                    print_line(rate, &e, &stream.stats(), a.json)?;
                }
                window = BiasEstimator::new();
                win_start = now_ns;
                win_n = 0;
            }
        }
        let elapsed_s = (clock.now_ns() - t0) as f64 * 1e-9;
        let st = stream.stats();
        let n = st.samples - start_stats.samples;
        let rate = n as f64 / elapsed_s;
        let result = stream.finish().await;
        let est = all.estimate();
        if mode == Mode::Check {
            let mut problems = Vec::new();
            if rate < 0.95 * ft.rate_hz {
                problems.push(format!(
                    "rate {rate:.0} Hz is below the configured {:.0} Hz",
                    ft.rate_hz
                ));
            }
            if st.lost > 0 {
                problems.push(format!("{} records lost", st.lost));
            }
            let bad = st.garbage + st.truncated + st.checksum_errors;
            if bad > 0 {
                problems.push(format!("{bad} bad records or garbage"));
            }
            if st.saturated > 0 {
                problems.push(format!("{} saturated samples", st.saturated));
            }
            if let Some(e) = &est {
                for i in 0..6 {
                    let limit = 10.0 * rig_core::ft::NANO17_SI_25_RESOLUTION[i];
                    if e.std[i] > limit {
                        problems.push(format!(
                            "{} noise {:.4} exceeds {:.4} {}",
                            AXES[i],
                            e.std[i],
                            limit,
                            if i < 3 { "N" } else { "N·mm" }
                        ));
                    }
                }
            }
            if let Err(e) = &result {
                problems.push(e.to_string());
            }
            println!("{n} samples in {elapsed_s:.2} s: {rate:.0} Hz; {flagged} flagged; {st}");
            if problems.is_empty() {
                println!("F/T check passed");
                return Ok(());
            }
            bail!("F/T check failed:\n  {}", problems.join("\n  "));
        }
        result?;
        Ok(())
    })
}

fn print_tare(t: &crate::force::TareReport, json: bool) -> anyhow::Result<()> {
    if json {
        println!(
            "{}",
            serde_json::to_string(&serde_json::json!({ "tare": t }))?
        );
        return Ok(());
    }
    println!("tare over {} samples (sensor frame):", t.raw.n);
    for i in 0..6 {
        let u = if i < 3 { "N" } else { "N·mm" };
        println!(
            "  {}: bias {:>10.4} {u}  noise σ {:.4} {u}  (± {:.5} {u})",
            AXES[i], t.wrench.mean[i], t.wrench.std[i], t.wrench.std_error[i]
        );
    }
    Ok(())
}

fn print_line(
    rate: f64,
    e: &rig_core::ft::bias::BiasEstimate,
    st: &crate::force::FtStatsSnapshot,
    json: bool,
) -> anyhow::Result<()> {
    if json {
        println!(
            "{}",
            serde_json::to_string(
                &serde_json::json!({"rate_hz": rate, "mean": e.mean, "std": e.std, "stats": st})
            )?
        );
        return Ok(());
    }
    let m = e.mean;
    println!(
        "{rate:>6.0} Hz  F [{:>7.3} {:>7.3} {:>7.3}] N  T [{:>8.2} {:>8.2} {:>8.2}] N·mm  σF {:.4} N  lost {} bad {} sat {}",
        m[0],
        m[1],
        m[2],
        m[3],
        m[4],
        m[5],
        e.std[..3].iter().cloned().fold(0.0, f64::max),
        st.lost,
        st.garbage + st.truncated + st.checksum_errors,
        st.saturated
    );
    Ok(())
}
