//! The daemon's TOML configuration: the `[daemon]` table and one `[[machine]]` table per machine.
//!
//! ```toml
//! [daemon]
//! store = "machlink.db"       # default: machlink.db next to this file
//! socket = "/run/machlink.sock" # default: $XDG_RUNTIME_DIR/machlink.sock, else /tmp/machlink-$USER.sock
//!
//! [[machine]]
//! name = "router"
//! link = "grbl"               # the link decides which other keys the table takes
//! port = "/dev/ttyUSB0"
//! ```
//!
//! Every error names the file, the line and column, the machine and the key.

use machlink_protocols::kind::{AnyKind, KindSettings, Registry};
use serde::de::{self, DeserializeSeed, Deserializer, MapAccess, Visitor};
use serde::{Deserialize, Serialize};
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::sync::Arc;
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
    pub fleet: Option<crate::fleet::FleetConfig>,
    /// `[[webhook]]`: URLs that get a POST of chosen events.
    pub webhooks: Vec<crate::webhooks::WebhookConfig>,
    /// The `[access]` table: tokens, local users and groups, socket group, audit log
    /// (`crate::access`).
    pub access: crate::access::AccessConfig,
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

/// One `[[machine]]` table: the keys every machine takes, and its kind's own settings.
#[derive(Clone)]
pub struct MachineConfig {
    pub name: String,
    /// The table's `link = "…"`: the kind of machine.
    pub link: String,
    /// The kind, from the registry the config was read with.
    pub kind: Arc<dyn AnyKind>,
    /// The kind's own keys, parsed and checked by the kind.
    pub settings: KindSettings,
    /// Where the tool may go, in work coordinates, mm.
    pub work_area: Option<WorkArea>,
    /// The fastest cutting feed the machine accepts, mm/min.
    pub max_feed: Option<f64>,
    /// M-codes a G-code job may hold (default: those GRBL runs, see `DEFAULT_M_CODES`).
    pub allowed_m_codes: Vec<u32>,
    /// The tools in the machine's rack.
    pub tools: Vec<ToolConfig>,
}

/// M-codes a G-code job may hold unless a machine says otherwise: program stop and end,
/// spindle, coolant (the ones GRBL 1.1 runs).
pub const DEFAULT_M_CODES: [u32; 10] = [0, 1, 2, 3, 4, 5, 7, 8, 9, 30];

impl std::fmt::Debug for MachineConfig {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.debug_struct("MachineConfig")
            .field("name", &self.name)
            .field("link", &self.link)
            .field("settings", &self.settings)
            .field("work_area", &self.work_area)
            .field("max_feed", &self.max_feed)
            .field("allowed_m_codes", &self.allowed_m_codes)
            .field("tools", &self.tools)
            .finish()
    }
}

impl PartialEq for MachineConfig {
    fn eq(&self, o: &MachineConfig) -> bool {
        self.name == o.name
            && self.link == o.link
            && self.settings == o.settings
            && self.work_area == o.work_area
            && self.max_feed == o.max_feed
            && self.allowed_m_codes == o.allowed_m_codes
            && self.tools == o.tools
    }
}

impl MachineConfig {
    /// A machine of kind `link` from `registry` with its settings given as a JSON table and
    /// no limits: for programs (the demo, tests) that build a config without a file.
    pub fn new(
        registry: &Registry,
        name: &str,
        link: &str,
        settings: serde_json::Value,
    ) -> Result<MachineConfig, String> {
        let kind = registry
            .kind(link)
            .ok_or_else(|| unknown_link(registry, link))?
            .clone();
        let settings = kind.settings(settings)?;
        Ok(MachineConfig {
            name: name.to_string(),
            link: link.to_string(),
            kind,
            settings,
            work_area: None,
            max_feed: None,
            allowed_m_codes: DEFAULT_M_CODES.to_vec(),
            tools: Vec::new(),
        })
    }
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
            out = format!(
                "{}{which}must have {n} values{axes}, got {got}",
                &out[..at]
            );
        }
    }
    out
}

fn unknown_link(registry: &Registry, link: &str) -> String {
    format!(
        "unknown link `{link}` (known: {})",
        registry.link_names().join(", ")
    )
}

/// A box the tool must stay inside, in work coordinates, mm.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorkArea {
    pub min: [f64; 3],
    pub max: [f64; 3],
}

/// A tool in the machine's rack.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ToolConfig {
    pub number: u32,
    /// Cutter diameter, mm.
    pub diameter: f64,
    #[serde(default)]
    pub name: Option<String>,
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
    fleet: Option<toml::Spanned<crate::fleet::FleetConfig>>,
    #[serde(default)]
    webhook: Vec<toml::Spanned<crate::webhooks::WebhookConfig>>,
    #[serde(default)]
    access: crate::access::RawAccess,
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
        Config::load_with(path, &crate::registry::standard())
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
        Config::parse_with(text, path, &crate::registry::standard())
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
                .map(|s| text.lines().nth(line_column(text, s.start).0 - 1).unwrap_or(""))
                .unwrap_or("");
            let mut message = in_operators_words(e.message().trim(), line);
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

impl MachineConfig {
    /// Checks the values serde cannot: positive feeds and scales, a non-empty box.
    fn check(&self) -> Result<(), String> {
        if self.name.trim().is_empty() {
            return Err("the name must not be empty".into());
        }
        if let Some(f) = self.max_feed {
            if !(f.is_finite() && f > 0.0) {
                return Err(format!(
                    "key `max_feed`: must be a positive number, got {f}"
                ));
            }
        }
        if let Some(w) = &self.work_area {
            for (i, axis) in ["X", "Y", "Z"].iter().enumerate() {
                if !(w.min[i].is_finite() && w.max[i].is_finite() && w.min[i] < w.max[i]) {
                    return Err(format!(
                        "key `work_area`: min {axis} {} must be below max {axis} {}",
                        w.min[i], w.max[i]
                    ));
                }
            }
        }
        for t in &self.tools {
            if !(t.diameter.is_finite() && t.diameter > 0.0) {
                return Err(format!(
                    "key `tools`: tool {}: the diameter must be a positive number, got {}",
                    t.number, t.diameter
                ));
            }
        }
        Ok(())
    }
}

/// How a machine table is called before its `name` key has been read (keys come in
/// alphabetical order); replaced by the name once the whole file is known.
const UNNAMED: &str = "a [[machine]] table";

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

/// The keys every machine table takes, whatever its link.
const COMMON_KEYS: [&str; 6] = [
    "name",
    "link",
    "work_area",
    "max_feed",
    "allowed_m_codes",
    "tools",
];

/// A `[[machine]]` table as written: the common keys typed, every other key kept with its
/// place in the file for the kind to read (and for errors to point at).
struct RawMachine {
    name: String,
    link: toml::Spanned<toml::Value>,
    work_area: Option<WorkArea>,
    max_feed: Option<f64>,
    allowed_m_codes: Option<Vec<u32>>,
    tools: Vec<ToolConfig>,
    others: Vec<(toml::Spanned<String>, toml::Spanned<toml::Value>)>,
}

impl<'de> Deserialize<'de> for RawMachine {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_map(MachineVisitor)
    }
}

struct MachineVisitor;

impl<'de> Visitor<'de> for MachineVisitor {
    type Value = RawMachine;

    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("a [[machine]] table")
    }

    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<RawMachine, A::Error> {
        let mut name: Option<String> = None;
        let mut link = None;
        let mut work_area = None;
        let mut max_feed = None;
        let mut allowed_m_codes = None;
        let mut tools = Vec::new();
        let mut others = Vec::new();
        let who = |name: &Option<String>| match name {
            Some(n) => format!("machine `{n}`"),
            None => UNNAMED.to_string(),
        };
        while let Some(key) = map.next_key::<toml::Spanned<String>>()? {
            let k = key.get_ref().clone();
            let ctx = |e: String| format!("{}: key `{k}`: {e}", who(&name));
            match k.as_str() {
                "name" => name = Some(map.next_value_seed(Named(ctx, std::marker::PhantomData))?),
                "link" => link = Some(map.next_value_seed(Named(ctx, std::marker::PhantomData))?),
                "work_area" => {
                    work_area = Some(map.next_value_seed(Named(ctx, std::marker::PhantomData))?)
                }
                "max_feed" => {
                    max_feed = Some(map.next_value_seed(Named(ctx, std::marker::PhantomData))?)
                }
                "allowed_m_codes" => {
                    allowed_m_codes =
                        Some(map.next_value_seed(Named(ctx, std::marker::PhantomData))?)
                }
                "tools" => tools = map.next_value_seed(Named(ctx, std::marker::PhantomData))?,
                _ => {
                    let v: toml::Spanned<toml::Value> =
                        map.next_value_seed(Named(ctx, std::marker::PhantomData))?;
                    others.push((key, v));
                }
            }
        }
        let name = name.ok_or_else(|| de::Error::custom("a [[machine]] table has no `name`"))?;
        let link = link.ok_or_else(|| {
            de::Error::custom(format!(
                "machine `{name}` has no `link` (say link = \"grbl\" or link = \"sim-grbl\")"
            ))
        })?;
        Ok(RawMachine {
            name,
            link,
            work_area,
            max_feed,
            allowed_m_codes,
            tools,
            others,
        })
    }
}

impl RawMachine {
    /// The machine, its kind found in `registry` and its kind's keys read by the kind; an
    /// error is a message and the place in the file it is about.
    fn resolve(
        self,
        registry: &Registry,
        table: std::ops::Range<usize>,
    ) -> Result<MachineConfig, (std::ops::Range<usize>, String)> {
        let name = self.name;
        let link_span = self.link.span();
        let link = match self.link.into_inner() {
            toml::Value::String(s) => s,
            _ => {
                return Err((
                    link_span,
                    format!("machine `{name}`: key `link` must be a string such as \"grbl\" or \"sim-grbl\""),
                ))
            }
        };
        let Some(kind) = registry.kind(&link) else {
            return Err((
                link_span,
                format!(
                    "machine `{name}`: key `link`: {}",
                    unknown_link(registry, &link)
                ),
            ));
        };
        let own: BTreeSet<&str> = kind.keys().into_iter().collect();
        let mut table_json = serde_json::Map::new();
        let mut spans = Vec::new();
        for (key, value) in &self.others {
            let k = key.get_ref();
            if !own.contains(k.as_str()) {
                let message = if registry.all_keys().contains(k.as_str()) {
                    format!(
                        "machine `{name}` (link = \"{link}\"): key `{k}` belongs to another kind of link (link = \"{link}\" takes {})",
                        list(&own)
                    )
                } else {
                    let mut known: Vec<&str> = COMMON_KEYS.to_vec();
                    known.extend(own.iter());
                    format!(
                        "machine `{name}`: unknown key `{k}` (a machine with link = \"{link}\" takes {})",
                        known.join(", ")
                    )
                };
                return Err((key.span(), message));
            }
            let json = serde_json::to_value(value.get_ref())
                .map_err(|e| (value.span(), format!("machine `{name}`: key `{k}`: {e}")))?;
            table_json.insert(k.clone(), json);
            spans.push((k.clone(), key.span()));
        }
        let settings = kind
            .settings(serde_json::Value::Object(table_json.clone()))
            .map_err(|message| {
                // name the key at fault: the one whose removal cures the complaint, else
                // one the complaint names, else one whose removal changes it (other than
                // into "missing key")
                let without = |k: &str| {
                    let mut t = table_json.clone();
                    t.remove(k);
                    kind.settings(serde_json::Value::Object(t))
                };
                let culprit = spans
                    .iter()
                    .find(|(k, _)| without(k).is_ok())
                    .or_else(|| {
                        spans
                            .iter()
                            .find(|(k, _)| message.contains(&format!("`{k}`")))
                    })
                    .or_else(|| {
                        spans.iter().find(|(k, _)| match without(k) {
                            Ok(_) => true,
                            Err(m2) => m2 != message && !m2.contains("missing"),
                        })
                    });
                match culprit {
                    Some((k, span)) => (
                        span.clone(),
                        format!("machine `{name}` (link = \"{link}\"): key `{k}`: {message}"),
                    ),
                    None => (
                        table.clone(),
                        format!("machine `{name}` (link = \"{link}\"): {message}"),
                    ),
                }
            })?;
        let m = MachineConfig {
            name,
            link,
            kind: kind.clone(),
            settings,
            work_area: self.work_area,
            max_feed: self.max_feed,
            allowed_m_codes: self
                .allowed_m_codes
                .unwrap_or_else(|| DEFAULT_M_CODES.to_vec()),
            tools: self.tools,
        };
        m.check()
            .map_err(|e| (table, format!("machine `{}`: {e}", m.name)))?;
        Ok(m)
    }
}

fn list(keys: &BTreeSet<&str>) -> String {
    if keys.is_empty() {
        "no keys of its own".into()
    } else {
        keys.iter().copied().collect::<Vec<_>>().join(", ")
    }
}

/// Deserializes a `T` in place and prefixes its error with the machine and key.
struct Named<F, T>(F, std::marker::PhantomData<T>);

impl<'de, F: FnOnce(String) -> String, T: Deserialize<'de>> DeserializeSeed<'de> for Named<F, T> {
    type Value = T;
    fn deserialize<D: Deserializer<'de>>(self, d: D) -> Result<T, D::Error> {
        T::deserialize(d).map_err(|e| de::Error::custom((self.0)(e.to_string())))
    }
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
        assert!(e.contains("`min` must have 3 values (X, Y, Z), got 2"), "{e}");
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
                spindle_dwell_s: 2.0
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
