//! `machlink`: the shop-floor daemon (`machlink serve`) and the operator's command line.
//! Every subcommand lives in `cmd/`; errors reach the operator as one plain sentence on
//! stderr and a non-zero exit status: 1 refused or failed, 2 usage, 3 daemon unreachable
//! (0 also when the reader of stdout went away early, as `| head` does).

mod cmd;

use clap::{CommandFactory, Parser, Subcommand};
use std::io::Write;

// the planning commands' heap (`offset_core::heap`): the system's allocator until a
// command that plans calls `hold_freed_memory`, which `serve` never does
#[global_allocator]
static HEAP: offset_core::heap::PlanningHeap = offset_core::heap::PlanningHeap;

/// The program's one-line description, in `machlink --help`.
const ABOUT: &str = "Offset tool paths and stitch paths, streamed to shop-floor machines";

#[derive(Parser)]
#[command(name = "machlink", version, about = ABOUT)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

/// `machlink plan` alone: clap builds every subcommand's arguments to parse any one of them
/// (about a million instructions, a third of a millisecond of `plan`'s start-up, issue 25),
/// so `plan`, the command run in loops, is parsed by a tree of its own. The same name,
/// version, description and doc line as in [`Cli`]: the same help and the same errors
/// (test `plan_alone_parses_and_refuses_as_the_whole_tree`).
#[derive(Parser)]
#[command(name = "machlink", version, about = ABOUT)]
struct PlanCli {
    #[command(subcommand)]
    command: PlanOnly,
}

#[derive(Subcommand)]
enum PlanOnly {
    /// Plan offline and write the program (G-code, DST, …).
    Plan(cmd::plan::PlanCmdArgs),
}

/// The command line, parsed: by [`PlanCli`] when the subcommand is `plan`.
fn parse() -> Cli {
    if std::env::args_os().nth(1).is_some_and(|a| a == "plan") {
        let PlanCli {
            command: PlanOnly::Plan(a),
        } = PlanCli::parse();
        return Cli {
            command: Command::Plan(a),
        };
    }
    Cli::parse()
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
    /// Replay a program against the stock: engagement, air cuts, removal rate, gouges.
    Simulate(cmd::simulate::SimulateArgs),
    /// Follow every job's state changes (for scripts and dashboards).
    Events(cmd::events::EventsArgs),
    /// The shop-floor dashboard in a browser: prints its URL (`--open` opens it).
    Dashboard(cmd::dashboard::DashboardArgs),
    /// Check a configuration file offline: every mistake with its line and key.
    CheckConfig(cmd::check_config::CheckConfigArgs),
    /// Print the shell completion script (bash, zsh, fish, …).
    Completions(cmd::completions::CompletionsArgs),
    /// Print or write the man pages.
    Man(cmd::completions::ManArgs),
    /// Tokens for the API: `token new --role operator --machines router,mill`.
    Token(cmd::access::TokenArgs),
    /// Take a machine's control lock (others can watch, not steer; `--break`: admins).
    Lock(cmd::access::LockArgs),
    /// Release a machine's control lock.
    Release(cmd::access::ReleaseArgs),
    /// List the machines' control locks.
    Locks(cmd::access::PlainArgs),
    /// Who the daemon takes you for: name, role, machines.
    Whoami(cmd::access::PlainArgs),
    /// Have the daemon reread its config's [access] table (admins).
    Reload(cmd::access::PlainArgs),
}

/// Exit statuses (docs/daemon.md): refused or failed, usage, daemon unreachable.
const EXIT_FAILED: i32 = 1;
const EXIT_UNREACHABLE: i32 = 3;

fn main() {
    cmd::STARTED.get_or_init(std::time::Instant::now);
    // a reader that closes stdout early (`machlink jobs --json | head -c 600`) ends the
    // command quietly with status 0, whichever command was printing: no panic message
    let default_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        if !is_closed_stdout(info.payload()) {
            default_hook(info);
        }
    }));
    let cli = parse();
    let outcome = std::panic::catch_unwind(move || run(cli));
    let result = match outcome {
        Ok(r) => r,
        Err(p) if is_closed_stdout(p.as_ref()) => std::process::exit(0),
        Err(p) => std::panic::resume_unwind(p),
    };
    if let Err(e) = result {
        if e.chain().any(|c| {
            c.downcast_ref::<std::io::Error>()
                .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
        }) {
            std::process::exit(0);
        }
        let unreachable = e.chain().any(|c| {
            matches!(
                c.downcast_ref::<machlink::faces::client::ClientError>(),
                Some(
                    machlink::faces::client::ClientError::Unreachable(_)
                        | machlink::faces::client::ClientError::PermissionDenied(_)
                )
            )
        });
        // one sentence: the chain of causes joined, no backtrace, nothing a device sent that
        // could steer the terminal
        let msg = e
            .chain()
            .map(|c| c.to_string())
            .collect::<Vec<_>>()
            .join(": ");
        let msg = machlink_protocols::untrusted::printable(&msg, 4096);
        let _ = writeln!(std::io::stderr(), "machlink: {msg}");
        std::process::exit(if unreachable {
            EXIT_UNREACHABLE
        } else {
            EXIT_FAILED
        });
    }
}

/// Whether a panic is std's "failed printing to stdout" of a closed pipe.
fn is_closed_stdout(payload: &(dyn std::any::Any + Send)) -> bool {
    let text = payload
        .downcast_ref::<String>()
        .map(String::as_str)
        .or_else(|| payload.downcast_ref::<&str>().copied())
        .unwrap_or("");
    // std's println! ("failed printing to stdout: Broken pipe") and a library's
    // `expect` on a write (clap_complete's "failed to write …: Os { kind: BrokenPipe }")
    (text.starts_with("failed printing to stdout") && text.contains("Broken pipe"))
        || text.contains("kind: BrokenPipe")
}

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
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
        Command::Simulate(a) => cmd::simulate::run(a),
        Command::Events(a) => cmd::events::run(a),
        Command::Dashboard(a) => cmd::dashboard::run(a),
        Command::CheckConfig(a) => cmd::check_config::run(a),
        Command::Completions(a) => cmd::completions::completions(a, Cli::command()),
        Command::Man(a) => cmd::completions::man(a, Cli::command()),
        Command::Token(a) => cmd::access::token(a),
        Command::Lock(a) => cmd::access::lock(a),
        Command::Release(a) => cmd::access::release(a),
        Command::Locks(a) => cmd::access::locks(a),
        Command::Whoami(a) => cmd::access::whoami(a),
        Command::Reload(a) => cmd::access::reload(a),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plan_alone_parses_and_refuses_as_the_whole_tree() {
        let help = |mut c: clap::Command| {
            c.build();
            c.find_subcommand_mut("plan")
                .expect("a plan subcommand")
                .render_long_help()
                .to_string()
        };
        assert_eq!(help(PlanCli::command()), help(Cli::command()));
        for argv in [
            "machlink plan gear.json --op pocket --tool-diameter 3 -o out.nc --timings",
            "machlink plan gear.json -o out.nc --post linuxcnc --stepover 40% --depth 1",
            "machlink plan",
            "machlink plan gear.json",
            "machlink plan gear.json -o out.nc --no-such-option",
            "machlink plan gear.json -o out.nc --tool-diameter",
            "machlink plan gear.json -o out.nc --timing",
            "machlink plan --help",
            "machlink plan -h",
            "machlink plan --version",
            "machlink plan a.json b.json -o out.nc",
        ] {
            let words = argv.split(' ');
            let whole = Cli::try_parse_from(words.clone());
            let alone = PlanCli::try_parse_from(words);
            match (whole, alone) {
                (Ok(w), Ok(a)) => {
                    let (Command::Plan(w), PlanOnly::Plan(a)) = (w.command, a.command) else {
                        panic!("{argv}: not parsed as plan");
                    };
                    assert_eq!(
                        (w.file, w.output, w.post, w.timings),
                        (a.file, a.output, a.post, a.timings),
                        "{argv}"
                    );
                }
                (Err(w), Err(a)) => {
                    assert_eq!(w.kind(), a.kind(), "{argv}");
                    assert_eq!(w.render().to_string(), a.render().to_string(), "{argv}");
                }
                (w, a) => panic!("{argv}: whole tree {:?}, plan alone {:?}", w.err(), a.err()),
            }
        }
    }
}
