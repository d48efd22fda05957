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

use std::io::Write;
use std::net::{IpAddr, SocketAddr};

use anyhow::{Context, bail};
use clap::{Parser, Subcommand, ValueEnum};
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
        }
    })
}
