//! The daemon's TOML configuration: the `[daemon]` table and one `[[machine]]` table per machine.
//!
//! ```toml
//! [daemon]
//! store = "machlink.db"       # default: machlink.db next to this file
//! socket = "/run/machlink.sock" # default: $XDG_RUNTIME_DIR/machlink.sock, else /tmp/machlink-$USER/machlink.sock
//!
//! [[machine]]
//! name = "router"
//! link = "grbl"               # the link decides which other keys the table takes
//! port = "/dev/ttyUSB0"
//! ```
//!
//! Every error names the file, the line and column, the machine and the key.
//!
//! The file is assembled here, above the modules whose tables it holds: each table is parsed
//! and checked by its owner (`core::machine` the `[[machine]]` tables, `services::access`
//! `[access]`, `services::fleet` `[fleet]`, `services::webhooks` `[[webhook]]`), none of which
//! reaches back up to this module.

use crate::core::machine::{MachineConfig, RawMachine, UNNAMED};
use machlink_protocols::kind::Registry;
use serde::Deserialize;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Why a configuration could not be used.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read {path}: {source}")]
    Read {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}, line {line}, column {column} (`{text}`): {message}")]
    Invalid {
        path: String,
        line: usize,
        column: usize,
        /// The line as written, which names the key.
        text: String,
        message: String,
    },
    #[error("{path}: {message}")]
    Whole { path: String, message: String },
}

/// The whole configuration, resolved: defaults filled in, paths made absolute where they
/// depend on the config file's place.
#[derive(Clone, Debug, PartialEq)]
pub struct Config {
    pub daemon: DaemonConfig,
    pub machines: Vec<MachineConfig>,
    /// `[fleet]`: the daemon shares a queue and a view with others on NATS JetStream.
    pub fleet: Option<crate::services::fleet::FleetConfig>,
    /// `[[webhook]]`: URLs that get a POST of chosen events.
    pub webhooks: Vec<crate::services::webhooks::WebhookConfig>,
    /// The `[access]` table: tokens, local users and groups, socket group, audit log
    /// (`crate::services::access`).
    pub access: crate::services::access::AccessConfig,
}

/// The `[daemon]` table, resolved.
#[derive(Clone, Debug, PartialEq)]
pub struct DaemonConfig {
    /// The SQLite job store.
    pub store: PathBuf,
    /// The Unix socket the API listens on.
    pub socket: PathBuf,
    /// Flush the journal after this many acknowledged units (1, the default: every one;
    /// and at least every `journal_max_lag`).
    pub journal_every: usize,
    /// The longest the journal may lag the device's acknowledgements.
    pub journal_max_lag: Duration,
}

/// The file as written: the `[daemon]` table and the machine tables.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawConfig {
    #[serde(default)]
    daemon: RawDaemon,
    #[serde(default)]
    machine: Vec<toml::Spanned<RawMachine>>,
    #[serde(default)]
    fleet: Option<toml::Spanned<crate::services::fleet::FleetConfig>>,
    #[serde(default)]
    webhook: Vec<toml::Spanned<crate::services::webhooks::WebhookConfig>>,
    #[serde(default)]
    access: crate::services::access::RawAccess,
}

#[derive(Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawDaemon {
    store: Option<PathBuf>,
    socket: Option<PathBuf>,
    journal_every: Option<toml::Spanned<usize>>,
    journal_max_lag_ms: Option<toml::Spanned<u64>>,
}

/// The socket path used when the config names none: `$XDG_RUNTIME_DIR/machlink.sock`
/// (a folder only its user can enter), else `/tmp/machlink-$USER/machlink.sock` (a folder
/// the daemon creates 0700).
pub fn default_socket() -> PathBuf {
    match std::env::var_os("XDG_RUNTIME_DIR") {
        Some(dir) if !dir.is_empty() => PathBuf::from(dir).join("machlink.sock"),
        _ => {
            let user = std::env::var("USER").unwrap_or_else(|_| "user".into());
            PathBuf::from(format!("/tmp/machlink-{user}/machlink.sock"))
        }
    }
}

impl Config {
    /// A configuration with no machines and every default; the store is `./machlink.db`.
    pub fn empty() -> Config {
        Config {
            daemon: DaemonConfig {
                store: PathBuf::from("machlink.db"),
                socket: default_socket(),
                journal_every: 1,
                journal_max_lag: Duration::from_secs(1),
            },
            machines: Vec::new(),
            fleet: None,
            webhooks: Vec::new(),
            access: Default::default(),
        }
    }

    /// Reads and checks a config file with the standard machine kinds.
    pub fn load(path: &Path) -> Result<Config, ConfigError> {
        Config::load_with(path, &crate::core::registry::standard())
    }

    /// Reads and checks a config file whose machines are of the kinds in `registry`.
    pub fn load_with(path: &Path, registry: &Registry) -> Result<Config, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.display().to_string(),
            source,
        })?;
        Config::parse_with(&text, path, registry)
    }

    /// Parses config text with the standard machine kinds; `path` names the file in errors
    /// and anchors relative paths.
    pub fn parse(text: &str, path: &Path) -> Result<Config, ConfigError> {
        Config::parse_with(text, path, &crate::core::registry::standard())
    }

    /// Parses config text whose machines are of the kinds in `registry`.
    pub fn parse_with(text: &str, path: &Path, registry: &Registry) -> Result<Config, ConfigError> {
        let file = path.display().to_string();
        let at = |span: Option<std::ops::Range<usize>>, message: String| match span {
            Some(s) => {
                let (line, column) = line_column(text, s.start);
                ConfigError::Invalid {
                    path: file.clone(),
                    line,
                    column,
                    text: text.lines().nth(line - 1).unwrap_or("").trim().to_string(),
                    message,
                }
            }
            None => ConfigError::Whole {
                path: file.clone(),
                message,
            },
        };
        let raw: RawConfig = toml::from_str(text).map_err(|e| {
            let line = e
                .span()
                .map(|s| {
                    text.lines()
                        .nth(line_column(text, s.start).0 - 1)
                        .unwrap_or("")
                })
                .unwrap_or("");
            let mut message = in_operators_words(e.message().trim(), line);
            if let Some(table) = e.span().and_then(|s| table_at(text, s.start)) {
                if !table.starts_with("[[machine") && !message.starts_with('[') {
                    message = format!("{table}: {message}");
                }
            }
            if let Some(name) = e.span().and_then(|s| machine_at(text, s.start)) {
                message = message.replace(UNNAMED, &format!("machine `{name}`"));
            }
            at(e.span(), message)
        })?;
        let dir = path.parent().unwrap_or(Path::new("."));
        let resolve = |p: PathBuf| if p.is_relative() { dir.join(p) } else { p };
        let mut cfg = Config::empty();
        cfg.daemon.store = resolve(raw.daemon.store.unwrap_or_else(|| "machlink.db".into()));
        if let Some(s) = raw.daemon.socket {
            cfg.daemon.socket = resolve(s);
        }
        if let Some(n) = raw.daemon.journal_every {
            let (span, n) = (n.span(), n.into_inner());
            if n == 0 {
                return Err(at(
                    Some(span),
                    "[daemon] key `journal_every`: must be 1 or more".into(),
                ));
            }
            cfg.daemon.journal_every = n;
        }
        if let Some(ms) = raw.daemon.journal_max_lag_ms {
            let (span, ms) = (ms.span(), ms.into_inner());
            if ms == 0 || ms > 1000 {
                return Err(at(
                    Some(span),
                    format!("[daemon] key `journal_max_lag_ms`: must be 1 to 1000, got {ms}"),
                ));
            }
            cfg.daemon.journal_max_lag = Duration::from_millis(ms);
        }
        for m in raw.machine {
            let span = m.span();
            let m = m
                .into_inner()
                .resolve(registry, span.clone())
                .map_err(|(span, message)| at(Some(key_span(text, span, &message)), message))?;
            let mut m = m;
            if let Some(r) = m.recipe.take() {
                // the machine's default recipe: read now, so a broken one is a config error
                let r = resolve(r);
                crate::core::intake::recipe::Recipe::from_path(&r).map_err(|e| {
                    let message = format!("machine `{}`: key `recipe`: {e}", m.name);
                    at(Some(key_span(text, span.clone(), &message)), message)
                })?;
                m.recipe = Some(r);
            }
            if cfg.machines.iter().any(|o| o.name == m.name) {
                return Err(at(
                    Some(span),
                    format!("machine `{}` is declared twice", m.name),
                ));
            }
            cfg.machines.push(m);
        }
        for (i, w) in raw.webhook.into_iter().enumerate() {
            let span = w.span();
            let w = w.into_inner();
            w.check().map_err(|m| {
                at(
                    Some(key_span(text, span, &m)),
                    format!("[[webhook]] {}: {m}", i + 1),
                )
            })?;
            cfg.webhooks.push(w);
        }
        if let Some(f) = raw.fleet {
            let span = f.span();
            let mut f = f.into_inner();
            let names: Vec<String> = cfg.machines.iter().map(|m| m.name.clone()).collect();
            f.check(&names)
                .map_err(|m| at(Some(key_span(text, span, &m)), format!("[fleet]: {m}")))?;
            f.credentials = f.credentials.map(resolve);
            cfg.fleet = Some(f);
        }
        let names: Vec<&str> = cfg.machines.iter().map(|m| m.name.as_str()).collect();
        cfg.access = raw.access.resolve(&names, dir).map_err(|m| at(None, m))?;
        Ok(cfg)
    }

    pub fn machine(&self, name: &str) -> Option<&MachineConfig> {
        self.machines.iter().find(|m| m.name == name)
    }
}

/// The name of the machine table that holds byte `offset`, if the file reads as TOML.
fn machine_at(text: &str, offset: usize) -> Option<String> {
    #[derive(Deserialize)]
    struct Names {
        #[serde(default)]
        machine: Vec<toml::Spanned<toml::Table>>,
    }
    let names: Names = toml::from_str(text).ok()?;
    names
        .machine
        .iter()
        .rfind(|m| m.span().start <= offset)
        .and_then(|m| m.get_ref().get("name")?.as_str().map(String::from))
}

/// The header of the table that holds byte `offset` (`[daemon]`, `[[webhook]]`, …), as
/// written; None before the first header.
fn table_at(text: &str, offset: usize) -> Option<String> {
    let offset = offset.min(text.len());
    let end = text[offset..].find('\n').map_or(text.len(), |n| offset + n);
    text[..end]
        .lines()
        .filter_map(|l| {
            let t = l.trim();
            (t.starts_with('[') && t.ends_with(']')).then(|| t.to_string())
        })
        .next_back()
}

/// Within a table's `span`, the line of the key a message names ("key `url`: …"), so the
/// error points at it; else the table.
fn key_span(text: &str, span: std::ops::Range<usize>, message: &str) -> std::ops::Range<usize> {
    let Some(key) = message
        .split("key `")
        .nth(1)
        .and_then(|r| r.split('`').next())
    else {
        return span;
    };
    // the table runs from its header to the next header
    let mut at = span.start;
    for (n, line) in text[span.start..].split_inclusive('\n').enumerate() {
        let t = line.trim_start();
        if n > 0 && t.starts_with('[') {
            break;
        }
        if t.strip_prefix(key)
            .is_some_and(|r| r.trim_start().starts_with('='))
        {
            let start = at + (line.len() - t.len());
            return start..start + key.len();
        }
        at += line.len();
    }
    span
}

/// 1-based line and column of byte `offset` in `text`.
fn line_column(text: &str, offset: usize) -> (usize, usize) {
    let before = &text[..offset.min(text.len())];
    let line = before.matches('\n').count() + 1;
    let column = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
    (line, column)
}

/// serde's phrases ("invalid type: string \"fast\", expected f64") in an operator's words
/// ("must be a number of mm/min, not \"fast\""); `line` is the line as written, whose key
/// says the unit.
pub fn in_operators_words(message: &str, line: &str) -> String {
    let key = line.split('=').next().unwrap_or("").trim();
    let unit = match key {
        "max_feed" | "feed" | "plunge_feed" => " of mm/min",
        k if k.ends_with("_ms") => " of milliseconds",
        k if k.ends_with("_s") => " of seconds",
        k if k.ends_with("_mm") => " of mm",
        _ => "",
    };
    let mut out = message.to_string();
    if let Some(at) = out.find("invalid type: ") {
        let rest = &out[at + "invalid type: ".len()..];
        if let Some((got, want)) = rest.split_once(", expected ") {
            let got = got
                .trim_start_matches("string ")
                .trim_start_matches("integer ")
                .trim_start_matches("floating point ")
                .trim_start_matches("boolean ")
                .trim_matches('`')
                .to_string();
            let want = want.trim();
            let (want, tail) = want.split_at(want.find(" for ").unwrap_or(want.len()));
            let wanted = match want {
                "f64" | "f32" => format!("a number{unit}"),
                "usize" | "u64" | "u32" | "u16" | "u8" | "i64" | "i32" => {
                    format!("a whole number{unit}")
                }
                "a boolean" => "true or false".to_string(),
                "a string" => "text in quotes".to_string(),
                other => other.to_string(),
            };
            out = format!("{}must be {wanted}, not {got}{tail}", &out[..at]);
        }
    }
    // "unknown field `colour`, expected one of `store`, `socket`"
    if let Some(at) = out.find("unknown field `") {
        let rest = &out[at + "unknown field `".len()..];
        if let Some((got, known)) = rest.split_once('`') {
            let known: Vec<&str> = known
                .split('`')
                .skip(1)
                .step_by(2)
                .filter(|k| !k.is_empty())
                .collect();
            let takes = if known.is_empty() {
                " (this table takes no keys)".to_string()
            } else {
                format!(" (this table takes {})", known.join(", "))
            };
            out = format!("{}unknown key `{got}`{takes}", &out[..at]);
        }
    }
    // "missing field `name`"
    if let Some(at) = out.find("missing field `") {
        let rest = &out[at + "missing field `".len()..];
        if let Some((key, tail)) = rest.split_once('`') {
            out = format!(
                "{}key `{key}` is missing; add `{key} = …`{tail}",
                &out[..at]
            );
        }
    }
    // "unknown variant `fast`, expected one of `a`, `b`"
    if let Some(at) = out.find("unknown variant `") {
        let rest = &out[at + "unknown variant `".len()..];
        if let Some((got, known)) = rest.split_once('`') {
            let known: Vec<&str> = known.split('`').skip(1).step_by(2).collect();
            let k = if key.is_empty() {
                "the value".to_string()
            } else {
                format!("`{key}`")
            };
            out = format!(
                "{}{k} must be one of {}, not \"{got}\"",
                &out[..at],
                known.join(", ")
            );
        }
    }
    if let Some(at) = out.find("invalid length ") {
        let rest = &out[at + "invalid length ".len()..];
        if let Some((got, want)) = rest.split_once(", expected an array of length ") {
            let n: String = want.chars().take_while(|c| c.is_ascii_digit()).collect();
            let after = want[n.len()..].trim_start_matches("in ").trim();
            let which = if after.is_empty() {
                String::new()
            } else {
                format!("{after} ")
            };
            let axes = if n == "3" { " (X, Y, Z)" } else { "" };
            out = format!("{}{which}must have {n} values{axes}, got {got}", &out[..at]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use machlink_protocols::grbl::kind::GrblSettings;
    use machlink_protocols::kind::Joined;
    use machlink_protocols::modbus::kind::{RtuLine, TcpAddress};
    use machlink_protocols::modbus::RingSettings;
    use machlink_sim::kinds::SimGrblSettings;

    fn parse(text: &str) -> Result<Config, String> {
        Config::parse(text, Path::new("/etc/machlink/cell.toml")).map_err(|e| e.to_string())
    }

    #[test]
    fn wrong_types_are_said_in_an_operators_words() {
        let e = parse("[[machine]]\nname = \"r\"\nlink = \"sim-grbl\"\nmax_feed = \"fast\"\n")
            .unwrap_err();
        assert!(
            e.contains("key `max_feed`: must be a number of mm/min, not \"fast\""),
            "{e}"
        );
        assert!(!e.contains("expected f64"), "{e}");
        let e = parse("[daemon]\njournal_every = \"often\"\n").unwrap_err();
        assert!(e.contains("must be a whole number, not \"often\""), "{e}");
        let e = parse(
            "[[machine]]\nname = \"r\"\nlink = \"sim-grbl\"\nwork_area = { min = [0, 0], max = [1, 1, 1] }\n",
        )
        .unwrap_err();
        assert!(
            e.contains("`min` must have 3 values (X, Y, Z), got 2"),
            "{e}"
        );
    }

    #[test]
    fn a_full_config_parses_with_defaults() {
        let c = parse(
            r#"
[daemon]
socket = "/run/ml.sock"

[[machine]]
name = "router"
link = "grbl"
port = "/dev/ttyUSB0"
max_feed = 3000
work_area = { min = [0, 0, -40], max = [600, 400, 10] }
tools = [ { number = 1, diameter = 3.0 } ]

[[machine]]
link = "sim-grbl"
name = "bench"
time_scale = 20
"#,
        )
        .unwrap();
        assert_eq!(c.daemon.store, PathBuf::from("/etc/machlink/machlink.db"));
        assert_eq!(c.daemon.socket, PathBuf::from("/run/ml.sock"));
        assert_eq!(c.machines.len(), 2);
        assert_eq!(c.machines[0].link, "grbl");
        assert_eq!(
            c.machines[0].settings.get::<GrblSettings>(),
            Some(&GrblSettings {
                port: "/dev/ttyUSB0".into(),
                baud: 115_200,
                check_first: false,
                auto_unlock: false,
                spindle_dwell_s: 2.0,
                silent_timeout_s: 20.0,
            })
        );
        assert_eq!(c.machines[0].max_feed, Some(3000.0));
        assert_eq!(c.machines[0].tools[0].diameter, 3.0);
        assert_eq!(c.machines[1].link, "sim-grbl");
        assert_eq!(
            c.machines[1].settings.get::<SimGrblSettings>(),
            Some(&SimGrblSettings {
                time_scale: 20.0,
                homing: false,
                spindle_dwell_s: 2.0,
                silent_timeout_s: 20.0,
            })
        );
    }

    #[test]
    fn an_unknown_key_names_file_line_column_machine_and_key() {
        let e =
            parse("[[machine]]\nname = \"mill\"\nlink = \"grbl\"\nport = \"/dev/x\"\nprot = 3\n")
                .unwrap_err();
        assert!(
            e.starts_with("/etc/machlink/cell.toml, line 5, column"),
            "{e}"
        );
        assert!(e.contains("machine `mill`") && e.contains("`prot`"), "{e}");
    }

    #[test]
    fn a_key_of_another_link_is_refused() {
        let e = parse(
            "[[machine]]\nname = \"mill\"\nlink = \"grbl\"\nport = \"/dev/x\"\ntime_scale = 3.0\n",
        )
        .unwrap_err();
        assert!(
            e.contains("machine `mill`")
                && e.contains("`time_scale` belongs to another kind of link"),
            "{e}"
        );
        assert!(e.contains("line 5"), "{e}");
    }

    #[test]
    fn a_bad_value_names_the_key_and_its_line() {
        let e = parse("[[machine]]\nname = \"mill\"\nlink = \"grbl\"\nport = \"/dev/x\"\nmax_feed = \"fast\"\n")
            .unwrap_err();
        assert!(
            e.contains("line 5") && e.contains("machine `mill`: key `max_feed`"),
            "{e}"
        );
        let e = parse(
            "[[machine]]\nname = \"mill\"\nlink = \"grbl\"\nport = \"/dev/x\"\nbaud = \"fast\"\n",
        )
        .unwrap_err();
        assert!(
            e.contains("machine `mill` (link = \"grbl\"): key `baud`"),
            "{e}"
        );
        let e = parse(
            "[[machine]]\nname = \"mill\"\nlink = \"grbl\"\nport = \"/dev/x\"\nmax_feed = -3\n",
        )
        .unwrap_err();
        assert!(
            e.contains("key `max_feed`: must be a positive number"),
            "{e}"
        );
        let e = parse("[[machine]]\nname = \"mill\"\nlink = \"grbll\"\n").unwrap_err();
        assert!(e.contains("machine `mill`") && e.contains("grbll"), "{e}");
        let e = parse("[[machine]]\nname = \"mill\"\nlink = \"grbl\"\n").unwrap_err();
        assert!(e.contains("machine `mill`") && e.contains("port"), "{e}");
        let e = parse("[daemon]\nsocket = 3\n").unwrap_err();
        assert!(e.contains("line 2") && e.contains("socket"), "{e}");
        let e = parse("[[machine]\n").unwrap_err();
        assert!(e.contains("line 1"), "{e}");
    }

    #[test]
    fn duplicate_machines_and_bad_boxes_are_refused() {
        let m = "[[machine]]\nname = \"a\"\nlink = \"sim-grbl\"\n";
        let e = parse(&format!("{m}{m}")).unwrap_err();
        assert!(e.contains("declared twice") && e.contains("line 4"), "{e}");
        let e = parse(&format!(
            "{m}work_area = {{ min = [0,0,0], max = [10,0,5] }}\n"
        ))
        .unwrap_err();
        assert!(e.contains("min Y"), "{e}");
    }

    #[test]
    fn the_documented_example_parses() {
        let text = include_str!("../../docs/machlink.example.toml");
        let c = Config::parse(text, Path::new("/srv/cell/machlink.toml")).unwrap();
        assert_eq!(c.daemon.store, PathBuf::from("/srv/cell/machlink.db"));
        assert_eq!(c.daemon.journal_every, 1);
        let names: Vec<&str> = c.machines.iter().map(|m| m.name.as_str()).collect();
        assert_eq!(names, ["router", "bench"]);
        assert_eq!(c.machines[0].tools.len(), 2);
    }

    #[test]
    fn modbus_tcp_and_rtu_share_the_ring_keys() {
        let c = parse(
            "[[machine]]\nname = \"plc\"\nlink = \"modbus-tcp\"\nhost = \"10.0.0.5\"\nunit = 3\ntimeout_ms = 200\n\n[[machine]]\nname = \"drive\"\nlink = \"modbus-rtu\"\nport = \"/dev/ttyUSB3\"\nparity = \"even\"\nunit = 7\n",
        )
        .unwrap();
        let tcp = c.machines[0]
            .settings
            .get::<Joined<TcpAddress, RingSettings>>()
            .unwrap();
        assert_eq!(
            (tcp.own.port, tcp.common.unit, tcp.common.timeout_ms),
            (502, 3, 200)
        );
        let rtu = c.machines[1]
            .settings
            .get::<Joined<RtuLine, RingSettings>>()
            .unwrap();
        assert_eq!((rtu.own.baud, rtu.common.unit), (115_200, 7));
        let e = parse("[[machine]]\nname = \"plc\"\nlink = \"modbus-tcp\"\nhost = \"h\"\nretries = \"many\"\n").unwrap_err();
        assert!(e.contains("line 5") && e.contains("key `retries`"), "{e}");
    }
}
