//! `machlink-sim modbus`: the simulated motion-block device's command line.

use super::{Faults, ModbusSim, SimConfig};
use machlink_protocols::modbus::WordOrder;
use std::path::PathBuf;
use std::time::Duration;

/// Serve a simulated Modbus motion-block device (register map in docs/modbus.md).
#[derive(Clone, Debug, clap::Args)]
pub struct ModbusArgs {
    /// Serve Modbus TCP on this address, e.g. 127.0.0.1:5020.
    #[arg(long, conflicts_with = "pty", required_unless_present = "pty")]
    pub tcp: Option<std::net::SocketAddr>,
    /// Serve Modbus RTU on a new pseudo-terminal and make PATH a symlink to it.
    #[arg(long)]
    pub pty: Option<PathBuf>,
    /// Unit id (slave address) the device answers to.
    #[arg(long, default_value_t = 1)]
    pub unit: u8,
    /// Address of header register 0.
    #[arg(long, default_value_t = 0)]
    pub base: u16,
    /// Ring capacity in blocks.
    #[arg(long, default_value_t = 64)]
    pub capacity: u16,
    /// Word order of 32-bit values: high-first or low-first.
    #[arg(long, default_value = "high-first")]
    pub word_order: WordOrder,
    /// Simulated seconds per wall second for motion ("inf" or 0: execute every block at once).
    #[arg(long, default_value_t = 1.0)]
    pub time_scale: f64,
    /// Rapid rate, mm/min.
    #[arg(long, default_value_t = 5000.0)]
    pub rapid_feed: f64,
    /// Acceleration, mm/s².
    #[arg(long, default_value_t = 500.0)]
    pub acceleration: f64,
    /// Pace every exchange as a serial line at this baud (10 bits per byte).
    #[arg(long)]
    pub line_baud: Option<u32>,
    /// Answer FC23 (read/write in one request) with Illegal Function, as devices that only
    /// know FC3, FC6 and FC16 do.
    #[arg(long)]
    pub no_read_write: bool,
    /// Carry out request N but send no reply (repeatable; requests count from 1).
    #[arg(long = "drop-reply", value_name = "N")]
    pub drop_replies: Vec<u64>,
    /// Carry out request N and answer it late: its reply ends --late-ms after the request
    /// began (repeatable).
    #[arg(long = "late-reply", value_name = "N")]
    pub late_replies: Vec<u64>,
    /// How late a late reply is, ms.
    #[arg(long, default_value_t = 1000)]
    pub late_ms: u64,
    /// Answer request N with exception CODE instead of carrying it out (N:CODE, repeatable).
    #[arg(long = "exception", value_name = "N:CODE", value_parser = parse_pair::<u64, u8>)]
    pub exceptions: Vec<(u64, u8)>,
    /// At request N hang up (TCP) or go deaf for --silence-ms (RTU) (repeatable).
    #[arg(long = "disconnect", value_name = "N")]
    pub disconnects: Vec<u64>,
    /// How long the RTU device stays deaf after a disconnect, ms.
    #[arg(long, default_value_t = 1000)]
    pub silence_ms: u64,
    /// Fault with CODE on reaching block SEQ (SEQ:CODE).
    #[arg(long, value_name = "SEQ:CODE", value_parser = parse_pair::<u32, u16>)]
    pub fault_at_block: Option<(u32, u16)>,
    /// Once block N has executed, hold and lose every request (no reply, nothing carried
    /// out) for --silent-for seconds; then answer again, still holding until resumed.
    #[arg(long, value_name = "N")]
    pub go_silent_at: Option<u32>,
    /// How long a --go-silent-at hang lasts, in seconds.
    #[arg(
        long,
        value_name = "SECS",
        default_value_t = 30.0,
        requires = "go_silent_at"
    )]
    pub silent_for: f64,
    /// Append every block written into the ring, every block executed and every sync to
    /// FILE, one JSON object per line.
    #[arg(long, value_name = "FILE")]
    pub trace: Option<PathBuf>,
}

fn parse_pair<A: std::str::FromStr, B: std::str::FromStr>(s: &str) -> Result<(A, B), String> {
    let (a, b) = s
        .split_once(':')
        .ok_or_else(|| format!("{s:?} is not of the form N:CODE"))?;
    let num = |t: &str| -> Option<u64> {
        match t.strip_prefix("0x") {
            Some(h) => u64::from_str_radix(h, 16).ok(),
            None => t.parse().ok(),
        }
    };
    let a = a
        .parse::<A>()
        .map_err(|_| format!("{a:?} in {s:?} is not a number in range"))?;
    let b = num(b)
        .and_then(|v| v.to_string().parse::<B>().ok())
        .ok_or_else(|| format!("{b:?} in {s:?} is not a number in range"))?;
    Ok((a, b))
}

impl ModbusArgs {
    pub fn config(&self) -> SimConfig {
        SimConfig {
            unit_id: self.unit,
            base_address: self.base,
            capacity: self.capacity,
            word_order: self.word_order,
            time_scale: self.time_scale,
            rapid_feed: self.rapid_feed,
            acceleration: self.acceleration,
            line_baud: self.line_baud,
            read_write: !self.no_read_write,
            faults: Faults {
                drop_replies: self.drop_replies.clone(),
                late_replies: self.late_replies.clone(),
                late_by: Duration::from_millis(self.late_ms),
                exceptions: self.exceptions.clone(),
                disconnects: self.disconnects.clone(),
                silence: Duration::from_millis(self.silence_ms),
                fault_at_block: self.fault_at_block,
                silent_after_block: self.go_silent_at.map(|n| {
                    (
                        n,
                        Duration::try_from_secs_f64(self.silent_for).unwrap_or_default(),
                    )
                }),
            },
        }
    }
}

/// Runs the device until Ctrl-C, printing where it listens and, at the end, what it executed.
pub async fn run(args: ModbusArgs) -> anyhow::Result<()> {
    let cfg = args.config();
    if cfg.capacity == 0 {
        anyhow::bail!("--capacity must be at least 1");
    }
    if cfg.time_scale.is_nan() || cfg.time_scale < 0.0 {
        anyhow::bail!("--time-scale must be a number >= 0 (or inf)");
    }
    if !(args.silent_for.is_finite() && args.silent_for >= 0.0) {
        anyhow::bail!(
            "--silent-for must be a number of seconds, 0 or more, got {}",
            args.silent_for
        );
    }
    let sim = match (&args.tcp, &args.pty) {
        (Some(addr), _) => {
            let sim = ModbusSim::spawn_tcp(cfg, *addr).await?;
            println!("modbus device listening on tcp {}", sim.addr());
            sim
        }
        (None, Some(path)) => {
            let sim = ModbusSim::spawn_pty(cfg, Some(path)).await?;
            println!("modbus device on pty {}", sim.port().display());
            sim
        }
        (None, None) => anyhow::bail!("give --tcp ADDR or --pty PATH"),
    };
    let mut file = match &args.trace {
        Some(p) => Some(
            std::fs::OpenOptions::new()
                .create(true)
                .append(true)
                .open(p)
                .map_err(|e| anyhow::anyhow!("cannot open the trace file {}: {e}", p.display()))?,
        ),
        None => None,
    };
    let mut written = 0usize;
    let ctrl_c = tokio::signal::ctrl_c();
    tokio::pin!(ctrl_c);
    loop {
        tokio::select! {
            r = &mut ctrl_c => { r?; break; }
            _ = tokio::time::sleep(Duration::from_millis(20)) => {
                if let Some(f) = file.as_mut() {
                    use std::io::Write;
                    let new = sim.events_from(written);
                    written += new.len();
                    let mut buf = Vec::new();
                    for e in &new {
                        buf.extend(serde_json::to_vec(e)?);
                        buf.push(b'\n');
                    }
                    if !buf.is_empty() {
                        f.write_all(&buf)?;
                        f.flush()?;
                    }
                }
            }
        }
    }
    let trace = sim.trace();
    println!("executed {} blocks; {:?}", trace.len(), sim.stats());
    Ok(())
}
