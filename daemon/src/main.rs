//! `machlink`: the shop-floor daemon (`machlink serve`) and the operator's command line.
//! Every subcommand lives in `cmd/`; errors reach the operator as one plain sentence on
//! stderr and a non-zero exit status.

mod cmd;

use clap::{CommandFactory, Parser, Subcommand};

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
    /// Follow a job's progress until it ends.
    Watch(cmd::operate::JobArgs),
    /// Hold a running job (feed hold).
    Pause(cmd::operate::JobArgs),
    /// Continue a held or paused job.
    Resume(cmd::operate::ResumeArgs),
    /// Cancel a job.
    Cancel(cmd::operate::JobArgs),
    /// Geometry only: offset a shape and write it.
    Offset(cmd::offset::OffsetArgs),
    /// Plan offline and write the program (G-code, DST, …).
    Plan(cmd::plan::PlanCmdArgs),
    /// Draw a shape, a plan or a program as SVG or PNG.
    Preview(cmd::preview::PreviewArgs),
    /// Follow every job's state changes (for scripts and dashboards).
    Events(cmd::events::EventsArgs),
    /// Check a configuration file offline: every mistake with its line and key.
    CheckConfig(cmd::check_config::CheckConfigArgs),
    /// Print the shell completion script (bash, zsh, fish, …).
    Completions(cmd::completions::CompletionsArgs),
    /// Print or write the man pages.
    Man(cmd::completions::ManArgs),
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
        Command::Offset(a) => cmd::offset::run(a),
        Command::Plan(a) => cmd::plan::run(a),
        Command::Preview(a) => cmd::preview::run(a),
        Command::Events(a) => cmd::events::run(a),
        Command::CheckConfig(a) => cmd::check_config::run(a),
        Command::Completions(a) => cmd::completions::completions(a, Cli::command()),
        Command::Man(a) => cmd::completions::man(a, Cli::command()),
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
