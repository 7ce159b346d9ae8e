//! `machlink-sim sewing`: a simulated pattern sewing machine on a pty, from the command line.

use anyhow::Context;
use std::io::Write;
use std::path::PathBuf;

/// Options of `machlink-sim sewing`.
#[derive(clap::Args, Debug)]
pub struct SewingArgs {
    /// Make this path a symbolic link to the machine's pty (an existing link is replaced).
    #[arg(long)]
    pub pty: PathBuf,
    /// Stitches per minute.
    #[arg(long, default_value_t = 2500)]
    pub spm: u32,
    /// Simulated seconds per wall second.
    #[arg(long, default_value_t = 1.0)]
    pub time_scale: f64,
    /// Probability per byte, each direction, of losing it or flipping a bit (0 to 0.1).
    #[arg(long, default_value_t = 0.0)]
    pub noise: f64,
    /// Seed of the line noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Break the thread before sewing record N (0-based; repeatable); the machine waits for RESUME.
    #[arg(long, value_name = "N")]
    pub thread_break_at: Vec<u32>,
    /// Lose power (and the pattern) before sewing record N (0-based; repeatable).
    #[arg(long, value_name = "N")]
    pub power_loss_at: Vec<u32>,
    /// Once N records are sewn, hold and hang for --silent-for seconds: every byte received
    /// is lost and nothing is answered (no STATUS); then answer again, held until RESUME.
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
    /// Sewing area in mm: X0,Y0,X1,Y1.
    #[arg(long, value_delimiter = ',', allow_hyphen_values = true, num_args = 4, default_values_t = [-150.0, -100.0, 150.0, 100.0])]
    pub area: Vec<f64>,
    /// The longest stitch or jump of one record, mm.
    #[arg(long, default_value_t = 12.7)]
    pub max_stitch: f64,
    /// Pace the line both ways as a UART at this baud rate would (10 bits a byte).
    #[arg(long)]
    pub baud: Option<u32>,
    /// The upload window INFO reports (chunk frames in flight); 0 behaves as a machine of
    /// protocol version 1 (no window in INFO, no NAK for a frame that stops short).
    #[arg(long, default_value_t = 4)]
    pub window: u8,
    /// Append every record the machine executes ({"event":"record","index","kind","x","y"},
    /// 0.1 mm) and every event ({"event":"note","text"}) to this file, one JSON object per line.
    #[arg(long)]
    pub trace: Option<PathBuf>,
}

impl SewingArgs {
    /// The machine these options describe; the error names the bad option.
    pub fn config(&self) -> anyhow::Result<super::SewingSimConfig> {
        if !(self.noise.is_finite() && (0.0..=0.1).contains(&self.noise)) {
            anyhow::bail!("--noise must be 0 to 0.1, got {}", self.noise);
        }
        if !(self.time_scale.is_finite() && self.time_scale > 0.0) {
            anyhow::bail!(
                "--time-scale must be a positive number, got {}",
                self.time_scale
            );
        }
        if self.baud == Some(0) {
            anyhow::bail!("--baud must be at least 1");
        }
        if self.spm == 0 {
            anyhow::bail!("--spm must be at least 1");
        }
        let a = &self.area;
        if a.len() != 4 || !a.iter().all(|v| v.is_finite()) || a[0] >= a[2] || a[1] >= a[3] {
            anyhow::bail!("--area must be X0,Y0,X1,Y1 with X0 < X1 and Y0 < Y1, got {a:?}");
        }
        if !(self.max_stitch.is_finite() && self.max_stitch >= 0.1 && self.max_stitch <= 6553.5) {
            anyhow::bail!(
                "--max-stitch must be 0.1 to 6553.5 mm, got {}",
                self.max_stitch
            );
        }
        if !(self.silent_for.is_finite() && self.silent_for >= 0.0) {
            anyhow::bail!(
                "--silent-for must be a number of seconds, 0 or more, got {}",
                self.silent_for
            );
        }
        let u = |v: f64| (v * 10.0).round() as i32;
        Ok(super::SewingSimConfig {
            spm: self.spm,
            time_scale: self.time_scale,
            noise: self.noise,
            seed: self.seed,
            thread_break_at: self.thread_break_at.clone(),
            power_loss_at: self.power_loss_at.clone(),
            silent_after: self
                .go_silent_at
                .map(|n| (n, std::time::Duration::from_secs_f64(self.silent_for))),
            area: [u(a[0]), u(a[1]), u(a[2]), u(a[3])],
            max_stitch: (self.max_stitch * 10.0).round() as u16,
            baud: self.baud,
            window: (self.window > 0).then_some(self.window),
        })
    }
}

/// Runs the machine until interrupted.
pub fn run(a: SewingArgs) -> anyhow::Result<()> {
    let cfg = a.config()?;
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    rt.block_on(async move {
        let sim = super::spawn_on_pty_at(cfg, Some(&a.pty)).with_context(|| {
            format!(
                "cannot open a pty for the sewing machine behind {}",
                a.pty.display()
            )
        })?;
        println!("{}", a.pty.display());
        eprintln!(
            "machlink-sim: pattern sewing machine on {} (pty {}); stop with Ctrl-C",
            a.pty.display(),
            sim.path
        );
        let mut written = 0usize;
        let mut file = match &a.trace {
            Some(p) => Some(
                std::fs::OpenOptions::new()
                    .create(true)
                    .append(true)
                    .open(p)
                    .with_context(|| format!("cannot open the trace file {}", p.display()))?,
            ),
            None => None,
        };
        loop {
            tokio::time::sleep(std::time::Duration::from_millis(20)).await;
            let lines = {
                let t = sim
                    .trace
                    .lock()
                    .map_err(|_| anyhow::anyhow!("the trace is poisoned"))?;
                t.lines[written..].to_vec()
            };
            if let Some(f) = file.as_mut() {
                for d in &lines {
                    writeln!(f, "{}", serde_json::to_string(d)?)?;
                }
                f.flush()?;
            }
            written += lines.len();
            if sim.task.is_finished() {
                anyhow::bail!("the machine stopped");
            }
        }
    })
}
