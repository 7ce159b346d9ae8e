//! `machlink`: the shop-floor daemon (`machlink serve`) and the operator's command line.
//! Every subcommand lives in `cmd/`; errors reach the operator as one plain sentence on
//! stderr and a non-zero exit status.

mod cmd;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "machlink",
    version,
    about = "Offset tool paths and stitch paths, streamed to shop-floor machines"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
#[allow(clippy::large_enum_variant)] // parsed once at start-up
enum Command {
    /// The embedded default: a daemon with a simulated GRBL machine streams a sample job.
    Demo(cmd::demo::DemoArgs),
    /// Run the daemon.
    Serve(cmd::serve::ServeArgs),
    /// Plan a job from a shape file and queue it on a machine.
    Submit(cmd::submit::SubmitArgs),
    /// List jobs.
    Jobs(cmd::operate::JobsArgs),
    /// List machines.
    Machines(cmd::operate::MachinesArgs),
    /// Follow a job's progress until it ends (a line per step when not on a terminal).
    Watch(cmd::operate::WatchArgs),
    /// Hold a running job (feed hold).
    Pause(cmd::operate::JobArgs),
    /// Continue a held or stopped job (shows what the machine will do and asks first).
    Resume(cmd::operate::ResumeArgs),
    /// Cancel a job.
    Cancel(cmd::operate::JobArgs),
    /// Clear a machine's alarm lock (GRBL `$X`), once its cause is cleared.
    Unlock(cmd::at_machine::MachineArgs),
    /// Run a machine's homing cycle (GRBL `$H`).
    Home(cmd::at_machine::MachineArgs),
    /// Move a machine's tool by a distance, between jobs (GRBL `$J=`).
    Jog(cmd::at_machine::JogArgs),
    /// Change a running job's feed, spindle or rapid override.
    Override(cmd::at_machine::OverrideArgs),
    /// Geometry only: offset a shape and write it.
    Offset(cmd::offset::OffsetArgs),
    /// Plan offline and write the program (G-code, DST, …).
    Plan(cmd::plan::PlanCmdArgs),
    /// Draw a shape, a plan or a program as SVG or PNG.
    Preview(cmd::preview::PreviewArgs),
}

fn main() {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Demo(a) => cmd::demo::run(a),
        Command::Serve(a) => cmd::serve::run(a),
        Command::Submit(a) => cmd::submit::run(a),
        Command::Jobs(a) => cmd::operate::jobs(a),
        Command::Machines(a) => cmd::operate::machines(a),
        Command::Watch(a) => cmd::operate::watch(a),
        Command::Pause(a) => cmd::operate::pause(a),
        Command::Resume(a) => cmd::operate::resume(a),
        Command::Cancel(a) => cmd::operate::cancel(a),
        Command::Unlock(a) => cmd::at_machine::unlock(a),
        Command::Home(a) => cmd::at_machine::home(a),
        Command::Jog(a) => cmd::at_machine::jog(a),
        Command::Override(a) => cmd::at_machine::override_job(a),
        Command::Offset(a) => cmd::offset::run(a),
        Command::Plan(a) => cmd::plan::run(a),
        Command::Preview(a) => cmd::preview::run(a),
    };
    if let Err(e) = result {
        // one sentence: the chain of causes joined, no backtrace
        let msg = e
            .chain()
            .map(|c| c.to_string())
            .collect::<Vec<_>>()
            .join(": ");
        eprintln!("machlink: {msg}");
        std::process::exit(1);
    }
}
