//! `machlink-sim`: run a simulated device on a pty or a TCP port.

use anyhow::Context;
use clap::{Args, Parser, Subcommand};
use machlink_sim::grbl::{GrblFault, GrblSim, GrblSimConfig};
use std::path::PathBuf;

#[derive(Parser)]
#[command(
    name = "machlink-sim",
    version,
    about = "Simulated machines for machlink"
)]
struct Cli {
    #[command(subcommand)]
    device: Device,
}

#[derive(Subcommand)]
enum Device {
    /// A GRBL 1.1 controller on a pseudo-terminal.
    Grbl(GrblArgs),
    /// A pattern sewing machine (pattern transfer protocol) on a pseudo-terminal.
    Sewing(machlink_sim::sewing::cli::SewingArgs),
    /// A Modbus motion-block device (PLC or drive) on TCP or on a pty (RTU).
    Modbus(machlink_sim::modbus::cli::ModbusArgs),
    /// CiA 402 servo drives (CANopen) behind an SLCAN adapter on a pseudo-terminal.
    Canopen(machlink_sim::canopen::cli::CanopenArgs),
}

#[derive(Args)]
struct GrblArgs {
    /// Make this path a symbolic link to the simulator's pty (an existing link is replaced).
    #[arg(long)]
    pty: PathBuf,
    /// Simulated seconds per wall second for motion ("inf" finishes every move at once).
    #[arg(long, default_value_t = 1.0)]
    time_scale: f64,
    /// Pace bytes both ways as a UART at this baud rate would (10 bits per byte).
    #[arg(long)]
    baud: Option<u32>,
    /// Answer error:CODE to the LINE-th G-code line received (1-based), e.g. 120:20.
    #[arg(long, value_name = "LINE:CODE", value_parser = parse_fault)]
    error_at: Vec<(u64, u8)>,
    /// Raise ALARM:CODE on the LINE-th G-code line received (1-based), e.g. 300:1.
    #[arg(long, value_name = "LINE:CODE", value_parser = parse_fault)]
    alarm_at: Vec<(u64, u8)>,
    /// Hang after answering the N-th G-code line (1-based): no `ok`, no answer to `?`, and
    /// every byte received is lost, for --silent-for seconds; then answer again.
    #[arg(long, value_name = "N")]
    go_silent_at: Option<u64>,
    /// How long a --go-silent-at hang lasts, in seconds.
    #[arg(
        long,
        value_name = "SECS",
        default_value_t = 30.0,
        requires = "go_silent_at"
    )]
    silent_for: f64,
    /// Receive buffer size in bytes.
    #[arg(long, default_value_t = 128)]
    rx_buffer: usize,
    /// Planner size in blocks.
    #[arg(long, default_value_t = 15)]
    planner_blocks: usize,
    /// Homing enabled ($22=1): start locked in alarm until $H (or $X); $H runs the cycle.
    #[arg(long)]
    homing: bool,
    /// A work offset at power-up, e.g. G55=10,20,0 (machine position of its zero, mm).
    #[arg(long, value_name = "G5x=X,Y,Z", value_parser = parse_offset)]
    offset: Vec<(usize, [f64; 3])>,
    /// Append every line received and every move executed to FILE, one JSON object per line.
    #[arg(long, value_name = "FILE")]
    trace: Option<PathBuf>,
}

fn parse_offset(s: &str) -> Result<(usize, [f64; 3]), String> {
    let (g, v) = s
        .split_once('=')
        .ok_or_else(|| format!("{s:?} is not G5x=X,Y,Z, e.g. G55=10,20,0"))?;
    let k = match g.trim().to_ascii_uppercase().as_str() {
        "G54" => 0,
        "G55" => 1,
        "G56" => 2,
        "G57" => 3,
        "G58" => 4,
        "G59" => 5,
        other => return Err(format!("{other:?} in {s:?} is not one of G54 to G59")),
    };
    let n: Vec<f64> = v
        .split(',')
        .map(|x| x.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("{v:?} in {s:?} is not three numbers X,Y,Z"))?;
    match n[..] {
        [x, y, z] if [x, y, z].iter().all(|v| v.is_finite()) => Ok((k, [x, y, z])),
        _ => Err(format!("{v:?} in {s:?} is not three numbers X,Y,Z")),
    }
}

fn parse_fault(s: &str) -> Result<(u64, u8), String> {
    let (l, c) = s
        .split_once(':')
        .ok_or_else(|| format!("{s:?} is not LINE:CODE, e.g. 120:20"))?;
    let line: u64 = l
        .trim()
        .parse()
        .map_err(|_| format!("line {l:?} in {s:?} is not a whole number"))?;
    if line == 0 {
        return Err(format!("line numbers count from 1, {s:?} names line 0"));
    }
    let code: u8 = c
        .trim()
        .parse()
        .map_err(|_| format!("code {c:?} in {s:?} is not a number from 0 to 255"))?;
    Ok((line, code))
}

fn run_grbl(a: GrblArgs) -> anyhow::Result<()> {
    let mut faults: Vec<GrblFault> = a
        .error_at
        .iter()
        .map(|&(line, code)| GrblFault::ErrorAtLine { line, code })
        .collect();
    faults.extend(
        a.alarm_at
            .iter()
            .map(|&(line, code)| GrblFault::AlarmAtLine { line, code }),
    );
    if let Some(line) = a.go_silent_at {
        faults.push(GrblFault::SilentAfterLine {
            line,
            seconds: a.silent_for,
        });
    }
    let mut work_offsets = [[0.0; 3]; 6];
    for (k, o) in &a.offset {
        work_offsets[*k] = *o;
    }
    let cfg = GrblSimConfig {
        time_scale: a.time_scale,
        baud: a.baud,
        rx_buffer: a.rx_buffer,
        planner_blocks: a.planner_blocks,
        faults,
        homing: a.homing,
        work_offsets,
        trace_file: a.trace.clone(),
        ..Default::default()
    };
    let sim = GrblSim::spawn_linked(cfg, &a.pty).with_context(|| {
        format!(
            "cannot start the simulated GRBL with its pty linked at {}",
            a.pty.display()
        )
    })?;
    println!("{}", a.pty.display());
    eprintln!(
        "machlink-sim: GRBL 1.1h on {}; stop with Ctrl-C",
        a.pty.display(),
    );
    let _keep = sim;
    loop {
        std::thread::park();
    }
}

fn main() {
    let cli = Cli::parse();
    let result = match cli.device {
        Device::Grbl(a) => run_grbl(a),
        Device::Sewing(a) => machlink_sim::sewing::cli::run(a),
        Device::Modbus(a) => tokio::runtime::Runtime::new()
            .context("cannot start the async runtime")
            .and_then(|rt| rt.block_on(machlink_sim::modbus::cli::run(a))),
        Device::Canopen(a) => tokio::runtime::Runtime::new()
            .context("cannot start the async runtime")
            .and_then(|rt| rt.block_on(machlink_sim::canopen::cli::run(a))),
    };
    if let Err(e) = result {
        eprintln!("machlink-sim: {e:#}");
        std::process::exit(1);
    }
}
