//! Screens that must tell the truth (issue 22), through the `machlink` binary:
//! `check-config` reports every mistake of a file in one run in an operator's words, clients
//! find the daemon the way README starts it, a socket the user may not open says so, a
//! reader that goes away ends a command quietly.

use crate::common;
use common::cli::{machlink, stderr, Serve};

use std::io::Read;
use std::os::unix::fs::PermissionsExt;
use std::os::unix::process::CommandExt;
use std::path::Path;
use std::process::Stdio;
use std::time::Duration;

/// A config with five mistakes that do not depend on each other, and the line and key each
/// one must be reported at, with the words the operator must read.
const FIVE_MISTAKES: &str = "\
[daemon]
socket = \"ml.sock\"
colour = \"red\"

[[machine]]
name = \"router\"
link = \"sim-grbl\"
max_feed = \"fast\"

[[machine]]
name = \"router\"
link = \"sim-grbl\"

[[webhook]]
url = \"http://127.0.0.1:9/hook\"
events = [\"completed\", \"exploded\"]

[fleet]
url = \"nats://127.0.0.1:4222\"
";

#[test]
fn check_config_reports_five_independent_mistakes_in_one_run() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("cell.toml");
    std::fs::write(&f, FIVE_MISTAKES).unwrap();
    let o = machlink().arg("check-config").arg(&f).output().unwrap();
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    let lines: Vec<&str> = err.lines().collect();
    assert_eq!(lines.len(), 5, "one sentence per mistake, all five: {err}");
    let file = f.display().to_string();
    for (line, key, words) in [
        (3, "`colour`", "unknown key `colour`"),
        (8, "`max_feed`", "must be a number of mm/min, not \"fast\""),
        (11, "`router`", "machine `router` is declared twice"),
        (16, "`events`", "unknown event `exploded`"),
        (18, "`name`", "[fleet]: key `name` is missing"),
    ] {
        let at = format!("machlink: {file}, line {line}");
        let got = lines
            .iter()
            .find(|l| l.starts_with(&format!("{at},")) || l.starts_with(&format!("{at}:")))
            .unwrap_or_else(|| panic!("nothing reported at line {line}: {err}"));
        assert!(
            got.contains(key) && got.contains(words),
            "line {line}: expected {key} and \"{words}\" in: {got}"
        );
    }
    for serde_words in ["invalid type", "expected f64", "missing field", "unknown field"] {
        assert!(!err.contains(serde_words), "serde's words `{serde_words}` in: {err}");
    }
}

/// `machlink serve --config cell.toml` in `dir` (its socket `ml.sock` there), as README
/// starts it.
fn serve_cell(dir: &Path) -> Serve {
    std::fs::write(
        dir.join("cell.toml"),
        "[daemon]\nstore = \"jobs.db\"\nsocket = \"ml.sock\"\n\n\
         [[machine]]\nname = \"router\"\nlink = \"sim-grbl\"\ntime_scale = 50.0\n",
    )
    .unwrap();
    let mut c = machlink();
    c.current_dir(dir)
        .args(["serve", "--config", "cell.toml"])
        .stdout(Stdio::null())
        .stderr(Stdio::null());
    Serve::spawn(c, &dir.join("ml.sock"), Duration::from_secs(30))
}

#[test]
fn machines_in_the_folder_of_serve_config_cell_toml_finds_its_socket() {
    let dir = tempfile::tempdir().unwrap();
    let _s = serve_cell(dir.path());
    // no --socket, no --config, no MACHLINK_*: only the cell.toml beside the operator
    let o = machlink()
        .current_dir(dir.path())
        .env_remove("XDG_RUNTIME_DIR")
        .args(["machines", "--json"])
        .output()
        .unwrap();
    assert!(o.status.success(), "machines: {}", stderr(&o));
    let m: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(m[0]["name"], "router", "{m}");
}

#[test]
fn the_socket_default_is_the_same_in_code_help_and_docs() {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let default = "$XDG_RUNTIME_DIR/machlink.sock";
    let fallback = "/tmp/machlink-$USER/machlink.sock";
    // the code: with and without XDG_RUNTIME_DIR, a client with no config tries the default
    let system = Path::new(SYSTEM_CONFIG).exists();
    if system {
        eprintln!("skipped the code's default: this host has {SYSTEM_CONFIG}, which clients read");
    }
    for (xdg, want) in [
        (Some("/run/user/4242"), "/run/user/4242/machlink.sock".to_string()),
        (None, "/tmp/machlink-alice/machlink.sock".to_string()),
    ]
    .into_iter()
    .filter(|_| !system)
    {
        let dir = tempfile::tempdir().unwrap();
        let mut c = machlink();
        c.current_dir(dir.path()).env("USER", "alice").arg("jobs");
        match xdg {
            Some(x) => c.env("XDG_RUNTIME_DIR", x),
            None => c.env_remove("XDG_RUNTIME_DIR"),
        };
        let o = c.output().unwrap();
        assert_eq!(o.status.code(), Some(3), "{}", stderr(&o));
        assert!(stderr(&o).contains(&want), "{want} in: {}", stderr(&o));
    }
    // --help of a client and of serve
    for args in [&["jobs", "--help"][..], &["serve", "--help"]] {
        let o = machlink().args(args).output().unwrap();
        let help = String::from_utf8_lossy(&o.stdout).replace(char::is_whitespace, "");
        for d in [default, fallback] {
            assert!(help.contains(d), "`machlink {}` names {d}: {help}", args.join(" "));
        }
    }
    // every page that names a default names this one
    for page in ["README.md", "docs/config.md", "docs/daemon.md"] {
        let text = std::fs::read_to_string(repo.join(page)).unwrap();
        let flat = text.replace(char::is_whitespace, "");
        assert!(
            flat.contains(&format!("`{default}`,else`{fallback}`"))
                || flat.contains(&format!("{default}`,else`{fallback}`")),
            "{page} gives the default socket as the code does"
        );
    }
}

const SYSTEM_CONFIG: &str = "/etc/machlink/machlink.toml";

/// The uid a test runs a client as when it runs as root, for whom file modes do not bite.
const NOBODY: u32 = 65534;

#[test]
fn a_socket_the_user_may_not_open_says_permission_denied_exit_3() {
    let dir = tempfile::tempdir().unwrap();
    let root = nix::unistd::Uid::effective().is_root();
    // a folder anyone may enter (nobody must reach the socket's folder), the daemon's own
    // inside it
    std::fs::set_permissions(dir.path(), std::fs::Permissions::from_mode(0o755)).unwrap();
    let cell = dir.path().join("cell");
    std::fs::create_dir(&cell).unwrap();
    std::fs::set_permissions(&cell, std::fs::Permissions::from_mode(0o755)).unwrap();
    let s = serve_cell(&cell);
    // the socket closed to everyone but root
    std::fs::set_permissions(&s.socket, std::fs::Permissions::from_mode(0o000)).unwrap();
    let mut c = machlink();
    c.arg("machines").arg("--socket").arg(&s.socket).current_dir("/");
    if root {
        // root opens any socket: the client runs as nobody, as an operator would
        c.uid(NOBODY).gid(NOBODY);
    }
    let o = c.output().unwrap();
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(3), "{err}");
    assert!(
        err.contains("permission denied:")
            && err.contains(&s.socket.display().to_string())
            && err.contains("(ask for a role, docs/security.md)"),
        "{err}"
    );
    assert!(!err.contains("is `machlink serve` running"), "{err}");
}

#[test]
fn every_command_ends_quietly_when_its_reader_goes_away() {
    for args in [
        &["completions", "zsh"][..],
        &["completions", "bash"],
        &["completions", "fish"],
        &["man"],
        &["--help"],
    ] {
        let mut child = machlink()
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        // the reader goes away before the first byte: every write meets a closed pipe
        drop(child.stdout.take());
        let mut err = String::new();
        child
            .stderr
            .take()
            .unwrap()
            .read_to_string(&mut err)
            .unwrap();
        let status = child.wait().unwrap();
        assert!(
            status.success() && err.is_empty(),
            "`machlink {}` with its reader gone: {status}, {err}",
            args.join(" ")
        );
    }
}
