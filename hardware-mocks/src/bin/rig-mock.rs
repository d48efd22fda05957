//! `rig-mock`: run a hardware mock as its own process.
//!
//! ```text
//! rig-mock ur5e --rtde-port 30004 --dashboard-port 29999 --script-port 30002 \
//!     [--host 127.0.0.1] [--robot-mode running|power-off] [--home-pose x,y,z,rx,ry,rz] \
//!     [--speed-factor F]
//! ```
//!
//! When every listener is bound it prints one line on stdout, `ur5e ready rtde=ADDR
//! dashboard=ADDR script=ADDR`, so a parent process can wait for it; logs go to stderr
//! (`RUST_LOG` filters them). SIGINT and SIGTERM shut it down cleanly.
//!
//! The simulated Nano17 front ends (see `hardware_mocks::nano17`), each under a constant load
//! `--load Fx,Fy,Fz,Tx,Ty,Tz` (N, N·mm; default none) with noise and a gauge offset:
//!
//! ```text
//! rig-mock nano17-serial [--rate-hz 1000] [--mode ascii|binary]   prints `nano17-serial ready pty=PATH`
//! rig-mock netft [--port 49152] [--host 127.0.0.1] [--rate-hz 7000] prints `netft ready addr=ADDR`
//! rig-mock nano17-daq [--rate-hz 1000]                             prints `nano17-daq ready pty=PATH`
//! ```

use std::io::Write;
use std::net::{IpAddr, SocketAddr};

use anyhow::{Context, bail};
use clap::{Parser, Subcommand, ValueEnum};
use hardware_mocks::nano17::{MockConfig, MockHandle};
use hardware_mocks::ur5e::{Ur5e, Ur5eConfig};
use rig_core::clock::Clock;
use rig_core::control::robot_mode;
use rig_core::pose::Pose;

#[derive(Parser, Debug)]
#[command(
    name = "rig-mock",
    about = "Simulated rig hardware, one mock per process"
)]
struct Cli {
    #[command(subcommand)]
    mock: Mock,
}

#[derive(Subcommand, Debug)]
enum Mock {
    /// A UR5e controller: RTDE, dashboard and secondary (script) interface.
    Ur5e(Ur5eArgs),
    /// An ATI F/T controller with a Nano17, on a pty (prints the pty path).
    #[command(name = "nano17-serial")]
    Nano17Serial(Nano17Args),
    /// An ATI Net F/T with a Nano17, on UDP.
    Netft(NetftArgs),
    /// A DAQ gauge stream of a Nano17, on a pty (prints the pty path).
    #[command(name = "nano17-daq")]
    Nano17Daq(Nano17Args),
}

#[derive(clap::Args, Debug)]
struct Nano17Args {
    /// Records per second.
    #[arg(long, default_value_t = rig_core::ft::DEFAULT_RATE_HZ)]
    rate_hz: f64,
    /// Serial controller output mode at power-up (the rig sets it with CD A / CD B anyway).
    #[arg(long, value_enum, default_value_t = ModeArg::Ascii)]
    mode: ModeArg,
    /// Constant true load Fx,Fy,Fz,Tx,Ty,Tz (N, N·mm).
    #[arg(long, value_parser = parse_pose, allow_hyphen_values = true)]
    load: Option<Pose>,
}

#[derive(ValueEnum, Clone, Copy, Debug)]
enum ModeArg {
    Ascii,
    Binary,
}

#[derive(clap::Args, Debug)]
struct NetftArgs {
    /// UDP port (49152 on a real Net F/T); 0 picks a free one.
    #[arg(long, default_value_t = rig_core::ft::netft::RDT_PORT)]
    port: u16,
    /// Address to listen on.
    #[arg(long, default_value = "127.0.0.1")]
    host: IpAddr,
    /// Records per second (a real Net F/T: up to 7000).
    #[arg(long, default_value_t = rig_core::ft::netft::MAX_RDT_RATE_HZ)]
    rate_hz: f64,
    /// Constant true load Fx,Fy,Fz,Tx,Ty,Tz (N, N·mm).
    #[arg(long, value_parser = parse_pose, allow_hyphen_values = true)]
    load: Option<Pose>,
}

fn load_source(load: Option<Pose>) -> hardware_mocks::truth::SharedWrenchSource {
    let w = load.map_or(rig_core::wrench::Wrench::ZERO, |p| {
        rig_core::wrench::Wrench::from_array(p.to_array())
    });
    std::sync::Arc::new(hardware_mocks::truth::ConstantWrench(w))
}

fn check_rate(rate_hz: f64) -> anyhow::Result<()> {
    if !(rate_hz.is_finite() && rate_hz > 0.0 && rate_hz <= 100_000.0) {
        bail!("--rate-hz must be in (0, 100000], got {rate_hz}");
    }
    Ok(())
}

fn ready(line: String) -> anyhow::Result<()> {
    let mut out = std::io::stdout().lock();
    writeln!(out, "{line}")?;
    out.flush()?;
    Ok(())
}

/// Prints the ready line, runs until SIGINT or SIGTERM, then shuts the F/T mock down.
async fn serve_until_signal<C: MockConfig>(
    mock: MockHandle<C>,
    ready_line: String,
) -> anyhow::Result<()> {
    ready(ready_line)?;
    wait_for_signal().await?;
    mock.shutdown().await;
    Ok(())
}

async fn run_nano17_serial(args: Nano17Args) -> anyhow::Result<()> {
    use hardware_mocks::nano17::{SensorModel, serial};
    check_rate(args.rate_hz)?;
    let cfg = serial::SerialMockConfig {
        rate_hz: args.rate_hz,
        mode: match args.mode {
            ModeArg::Ascii => rig_core::ft::serial::OutputMode::Ascii,
            ModeArg::Binary => rig_core::ft::serial::OutputMode::Binary,
        },
        ..serial::SerialMockConfig::default()
    };
    let mock = serial::SerialControllerMock::start(
        cfg,
        SensorModel::nano17(17),
        load_source(args.load),
        Clock::system(),
    )
    .context("could not open a pty for the simulated F/T controller")?;
    let line = format!("nano17-serial ready pty={}", mock.path().display());
    serve_until_signal(mock, line).await
}

async fn run_nano17_daq(args: Nano17Args) -> anyhow::Result<()> {
    use hardware_mocks::nano17::{SensorModel, daq};
    check_rate(args.rate_hz)?;
    let mock = daq::DaqMock::start(
        daq::DaqMockConfig {
            rate_hz: args.rate_hz,
            ..daq::DaqMockConfig::default()
        },
        SensorModel::nano17(18),
        load_source(args.load),
        Clock::system(),
    )
    .context("could not open a pty for the simulated DAQ")?;
    let line = format!("nano17-daq ready pty={}", mock.path().display());
    serve_until_signal(mock, line).await
}

async fn run_netft(args: NetftArgs) -> anyhow::Result<()> {
    use hardware_mocks::nano17::{SensorModel, netft};
    check_rate(args.rate_hz)?;
    let mock = netft::NetFtMock::start(
        netft::NetFtMockConfig {
            bind: SocketAddr::new(args.host, args.port),
            rate_hz: args.rate_hz,
            ..netft::NetFtMockConfig::default()
        },
        SensorModel::nano17(19),
        load_source(args.load),
        Clock::system(),
    )
    .await
    .with_context(|| {
        format!(
            "could not listen on UDP {}:{}: is another Net F/T mock running?",
            args.host, args.port
        )
    })?;
    let line = format!("netft ready addr={}", mock.addr());
    serve_until_signal(mock, line).await
}

#[derive(ValueEnum, Clone, Copy, Debug)]
enum RobotModeArg {
    /// Powered, brakes released: ready for a program.
    Running,
    /// Needs `power on` and `brake release` on the dashboard first.
    PowerOff,
}

#[derive(clap::Args, Debug)]
struct Ur5eArgs {
    /// RTDE port (30004 on a real controller); 0 picks a free one.
    #[arg(long, default_value_t = 30004)]
    rtde_port: u16,
    /// Dashboard port (29999 on a real controller).
    #[arg(long, default_value_t = 29999)]
    dashboard_port: u16,
    /// Secondary-interface port for scripts (30002 on a real controller).
    #[arg(long, default_value_t = 30002)]
    script_port: u16,
    /// Address to listen on.
    #[arg(long, default_value = "127.0.0.1")]
    host: IpAddr,
    /// robot_mode at start.
    #[arg(long, value_enum, default_value_t = RobotModeArg::PowerOff)]
    robot_mode: RobotModeArg,
    /// TCP pose at start: x,y,z (m), rx,ry,rz (rotation vector, rad).
    #[arg(long, value_parser = parse_pose, allow_hyphen_values = true)]
    home_pose: Option<Pose>,
    /// Run the simulated clock this many times faster than real time.
    #[arg(long, default_value_t = 1.0)]
    speed_factor: f64,
}

fn parse_pose(s: &str) -> Result<Pose, String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|p| p.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|e| format!("pose {s:?}: {e}"))?;
    let a: [f64; 6] = v
        .try_into()
        .map_err(|v: Vec<f64>| format!("pose needs 6 comma-separated numbers, got {}", v.len()))?;
    if a.iter().any(|x| !x.is_finite()) {
        return Err(format!("pose {s:?} has a non-finite value"));
    }
    Ok(Pose::from_array(a))
}

async fn run_ur5e(args: Ur5eArgs) -> anyhow::Result<()> {
    if !(args.speed_factor.is_finite() && args.speed_factor > 0.0) {
        bail!(
            "--speed-factor must be a positive number, got {}",
            args.speed_factor
        );
    }
    let mut cfg = Ur5eConfig {
        rtde_addr: SocketAddr::new(args.host, args.rtde_port),
        dashboard_addr: SocketAddr::new(args.host, args.dashboard_port),
        script_addr: SocketAddr::new(args.host, args.script_port),
        initial_robot_mode: match args.robot_mode {
            RobotModeArg::Running => robot_mode::RUNNING,
            RobotModeArg::PowerOff => robot_mode::POWER_OFF,
        },
        ..Ur5eConfig::default()
    };
    if let Some(p) = args.home_pose {
        cfg.home_pose = p;
    }
    let clock = Clock::scaled(args.speed_factor);
    let ur = Ur5e::start(cfg, clock).await.with_context(|| {
        format!(
            "could not listen on {} ports {}/{}/{}: is another controller or mock running?",
            args.host, args.rtde_port, args.dashboard_port, args.script_port
        )
    })?;
    {
        let mut out = std::io::stdout().lock();
        writeln!(
            out,
            "ur5e ready rtde={} dashboard={} script={}",
            ur.rtde_addr(),
            ur.dashboard_addr(),
            ur.script_addr()
        )?;
        out.flush()?;
    }
    wait_for_signal().await?;
    tracing::info!("signal received, shutting down");
    ur.shutdown().await;
    Ok(())
}

async fn wait_for_signal() -> anyhow::Result<()> {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{SignalKind, signal};
        let mut term = signal(SignalKind::terminate())?;
        let mut int = signal(SignalKind::interrupt())?;
        tokio::select! {
            _ = term.recv() => {}
            _ = int.recv() => {}
        }
    }
    #[cfg(not(unix))]
    tokio::signal::ctrl_c().await?;
    Ok(())
}

fn main() -> anyhow::Result<()> {
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        // Colour only on a terminal, so logs redirected to a file stay plain text.
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info")),
        )
        .init();
    let cli = Cli::parse();
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    rt.block_on(async {
        match cli.mock {
            Mock::Ur5e(args) => run_ur5e(args).await,
            Mock::Nano17Serial(args) => run_nano17_serial(args).await,
            Mock::Netft(args) => run_netft(args).await,
            Mock::Nano17Daq(args) => run_nano17_daq(args).await,
        }
    })
}
