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

use serde::de::{self, DeserializeOwned, DeserializeSeed, Deserializer, MapAccess, Visitor};
use serde::{Deserialize, Serialize};
use std::collections::BTreeSet;
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
}

/// The `[daemon]` table, resolved.
#[derive(Clone, Debug, PartialEq)]
pub struct DaemonConfig {
    /// The SQLite job store.
    pub store: PathBuf,
    /// The Unix socket the API listens on.
    pub socket: PathBuf,
    /// Flush the journal after this many acknowledged units (and at least every second).
    pub journal_every: usize,
    /// The longest the journal may lag the device's acknowledgements.
    pub journal_max_lag: Duration,
}

/// One `[[machine]]` table.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MachineConfig {
    pub name: String,
    /// The link and its settings (the table's `link` key and the keys that link takes).
    pub link: LinkConfig,
    /// Where the tool may go, in work coordinates, mm.
    pub work_area: Option<WorkArea>,
    /// The fastest cutting feed the machine accepts, mm/min.
    pub max_feed: Option<f64>,
    /// The tools in the machine's rack.
    pub tools: Vec<ToolConfig>,
}

/// The link to a machine, tagged by the `link` key. A new kind of machine adds a variant.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "link")]
pub enum LinkConfig {
    /// A GRBL controller on a serial port.
    #[serde(rename = "grbl")]
    Grbl(GrblLinkConfig),
    /// A GRBL simulator the daemon starts itself on a pseudo-terminal.
    #[serde(rename = "sim-grbl")]
    SimGrbl(SimGrblLinkConfig),
    /// A PLC or drive taking motion blocks over Modbus TCP.
    #[serde(rename = "modbus-tcp")]
    ModbusTcp(ModbusTcpLinkConfig),
    /// A PLC or drive taking motion blocks over Modbus RTU on a serial port.
    #[serde(rename = "modbus-rtu")]
    ModbusRtu(ModbusRtuLinkConfig),
    /// A pattern sewing machine on a serial port (pattern transfer protocol).
    #[serde(rename = "sewing")]
    Sewing(SewingLinkConfig),
    /// A simulated pattern sewing machine the daemon starts itself on a pseudo-terminal.
    #[serde(rename = "sim-sewing")]
    SimSewing(SimSewingLinkConfig),
}

impl LinkConfig {
    /// The `link` value of this variant, as written in the config.
    pub fn kind(&self) -> &'static str {
        match self {
            LinkConfig::Grbl(_) => "grbl",
            LinkConfig::SimGrbl(_) => "sim-grbl",
            LinkConfig::ModbusTcp(_) => "modbus-tcp",
            LinkConfig::ModbusRtu(_) => "modbus-rtu",
            LinkConfig::Sewing(_) => "sewing",
            LinkConfig::SimSewing(_) => "sim-sewing",
        }
    }

    /// Every key some link takes (to tell an unknown key from one of another link).
    fn all_keys() -> BTreeSet<&'static str> {
        let mut keys = BTreeSet::new();
        keys.extend(struct_fields::<GrblLinkConfig>());
        keys.extend(struct_fields::<SimGrblLinkConfig>());
        keys.extend(struct_fields::<ModbusTcpLinkConfig>());
        keys.extend(struct_fields::<ModbusRtuLinkConfig>());
        keys.extend(struct_fields::<SewingLinkConfig>());
        keys.extend(struct_fields::<SimSewingLinkConfig>());
        keys
    }
}

/// `link = "grbl"`: a GRBL 1.1 controller on a serial port.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GrblLinkConfig {
    /// The serial port, e.g. /dev/ttyUSB0.
    pub port: String,
    #[serde(default = "default_baud")]
    pub baud: u32,
    /// Run every program through GRBL's check mode ($C) before cutting.
    #[serde(default)]
    pub check_first: bool,
    /// Unlock ($X) a machine an earlier job left in alarm before the next job starts.
    /// Say false where an alarm must be looked at by someone first.
    #[serde(default = "yes")]
    pub auto_unlock: bool,
}

fn yes() -> bool {
    true
}

fn default_baud() -> u32 {
    115_200
}

/// `link = "sim-grbl"`: a simulated GRBL on a pseudo-terminal, started by the daemon.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimGrblLinkConfig {
    /// How many times faster than real time the simulated machine moves.
    #[serde(default = "default_time_scale")]
    pub time_scale: f64,
}

fn default_time_scale() -> f64 {
    1.0
}

/// `link = "modbus-tcp"`: motion blocks into a device's ring over Modbus TCP (docs/modbus.md).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModbusTcpLinkConfig {
    /// The device's host name or address.
    pub host: String,
    #[serde(default = "default_modbus_port")]
    pub port: u16,
    /// Unit id (1 unless a gateway routes by it).
    #[serde(default = "default_unit")]
    pub unit: u8,
    /// Address of header register 0.
    #[serde(default)]
    pub base_address: u16,
    /// "high-first" (default) or "low-first" for 32-bit values.
    #[serde(default)]
    pub word_order: machlink_protocols::modbus::WordOrder,
    /// The most registers per write (1 to 123; many drives take 10 or 12).
    #[serde(default = "default_max_write")]
    pub max_write_registers: u16,
    /// How long one request may wait for its reply, ms.
    #[serde(default = "default_modbus_timeout")]
    pub timeout_ms: u64,
    /// How often the device is polled while the ring is full, ms.
    #[serde(default = "default_poll")]
    pub poll_ms: u64,
    /// Failed attempts in a row (with backoff) before the job fails.
    #[serde(default = "default_retries")]
    pub retries: u32,
}

/// `link = "modbus-rtu"`: motion blocks into a device's ring over Modbus RTU (docs/modbus.md).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModbusRtuLinkConfig {
    /// The serial port, e.g. /dev/ttyUSB0.
    pub port: String,
    #[serde(default = "default_baud")]
    pub baud: u32,
    /// "none" (default), "even" or "odd".
    #[serde(default)]
    pub parity: machlink_protocols::modbus::Parity,
    /// The device's slave address, 1 to 247.
    #[serde(default = "default_unit")]
    pub unit: u8,
    #[serde(default)]
    pub base_address: u16,
    #[serde(default)]
    pub word_order: machlink_protocols::modbus::WordOrder,
    #[serde(default = "default_max_write")]
    pub max_write_registers: u16,
    #[serde(default = "default_modbus_timeout")]
    pub timeout_ms: u64,
    #[serde(default = "default_poll")]
    pub poll_ms: u64,
    #[serde(default = "default_retries")]
    pub retries: u32,
    /// After a timeout, how long the line must be silent before the next request, ms.
    #[serde(default = "default_modbus_timeout")]
    pub quiet_ms: u64,
}

fn default_modbus_port() -> u16 {
    502
}
fn default_unit() -> u8 {
    1
}
fn default_max_write() -> u16 {
    123
}
fn default_modbus_timeout() -> u64 {
    500
}
fn default_poll() -> u64 {
    20
}
fn default_retries() -> u32 {
    8
}

impl ModbusTcpLinkConfig {
    /// The link's settings.
    pub fn settings(&self) -> machlink_protocols::modbus::ModbusSettings {
        let mut s = machlink_protocols::modbus::ModbusSettings::tcp(&self.host, self.port);
        s.unit_id = self.unit;
        s.base_address = self.base_address;
        s.word_order = self.word_order;
        s.max_write_registers = self.max_write_registers;
        s.timeout = Duration::from_millis(self.timeout_ms);
        s.poll_interval = Duration::from_millis(self.poll_ms);
        s.max_retries = self.retries;
        s
    }
}

impl ModbusRtuLinkConfig {
    /// The link's settings.
    pub fn settings(&self) -> machlink_protocols::modbus::ModbusSettings {
        let mut s = machlink_protocols::modbus::ModbusSettings::rtu(&self.port, self.baud);
        s.transport = machlink_protocols::modbus::Transport::Rtu {
            path: self.port.clone(),
            baud: self.baud,
            parity: self.parity,
        };
        s.unit_id = self.unit;
        s.base_address = self.base_address;
        s.word_order = self.word_order;
        s.max_write_registers = self.max_write_registers;
        s.timeout = Duration::from_millis(self.timeout_ms);
        s.poll_interval = Duration::from_millis(self.poll_ms);
        s.max_retries = self.retries;
        s.rtu_quiet = Duration::from_millis(self.quiet_ms);
        s
    }
}

/// `link = "sewing"`: a pattern sewing machine on a serial port.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SewingLinkConfig {
    /// The serial port, e.g. /dev/ttyUSB1.
    pub port: String,
    #[serde(default = "default_baud")]
    pub baud: u32,
}

/// `link = "sim-sewing"`: a simulated pattern sewing machine on a pseudo-terminal, started
/// by the daemon (see `machlink-sim sewing` for the same machine from the command line).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimSewingLinkConfig {
    /// How many times faster than real time the simulated machine sews.
    #[serde(default = "default_time_scale")]
    pub time_scale: f64,
    /// Stitches per minute.
    #[serde(default = "default_spm")]
    pub spm: u32,
    /// Probability per byte, each direction, of line noise (lost or corrupted bytes).
    #[serde(default)]
    pub noise: f64,
    /// The thread breaks before these records (0-based).
    #[serde(default)]
    pub thread_break_at: Vec<u32>,
    /// The power fails (the pattern is lost) before these records (0-based).
    #[serde(default)]
    pub power_loss_at: Vec<u32>,
}

fn default_spm() -> u32 {
    2500
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
    machine: Vec<toml::Spanned<MachineConfig>>,
}

#[derive(Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawDaemon {
    store: Option<PathBuf>,
    socket: Option<PathBuf>,
    journal_every: Option<usize>,
    journal_max_lag_ms: Option<u64>,
}

/// The socket path used when the config names none: `$XDG_RUNTIME_DIR/machlink.sock`,
/// else `/tmp/machlink-$USER.sock`.
pub fn default_socket() -> PathBuf {
    match std::env::var_os("XDG_RUNTIME_DIR") {
        Some(dir) if !dir.is_empty() => PathBuf::from(dir).join("machlink.sock"),
        _ => {
            let user = std::env::var("USER").unwrap_or_else(|_| "user".into());
            PathBuf::from(format!("/tmp/machlink-{user}.sock"))
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
                journal_every: 50,
                journal_max_lag: Duration::from_secs(1),
            },
            machines: Vec::new(),
        }
    }

    /// Reads and checks a config file.
    pub fn load(path: &Path) -> Result<Config, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
            path: path.display().to_string(),
            source,
        })?;
        Config::parse(&text, path)
    }

    /// Parses config text; `path` names the file in errors and anchors relative paths.
    pub fn parse(text: &str, path: &Path) -> Result<Config, ConfigError> {
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
            let mut message = e.message().trim().to_string();
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
            if n == 0 {
                return Err(at(None, "[daemon] journal_every must be 1 or more".into()));
            }
            cfg.daemon.journal_every = n;
        }
        if let Some(ms) = raw.daemon.journal_max_lag_ms {
            if ms == 0 || ms > 1000 {
                return Err(at(
                    None,
                    format!("[daemon] journal_max_lag_ms must be 1 to 1000, got {ms}"),
                ));
            }
            cfg.daemon.journal_max_lag = Duration::from_millis(ms);
        }
        for m in raw.machine {
            let span = m.span();
            let m = m.into_inner();
            if let Err(message) = m.check() {
                return Err(at(Some(span), format!("machine `{}`: {message}", m.name)));
            }
            if cfg.machines.iter().any(|o| o.name == m.name) {
                return Err(at(
                    Some(span),
                    format!("machine `{}` is declared twice", m.name),
                ));
            }
            cfg.machines.push(m);
        }
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
                return Err(format!("max_feed must be a positive number, got {f}"));
            }
        }
        if let Some(w) = &self.work_area {
            for (i, axis) in ["X", "Y", "Z"].iter().enumerate() {
                if !(w.min[i].is_finite() && w.max[i].is_finite() && w.min[i] < w.max[i]) {
                    return Err(format!(
                        "work_area: min {axis} {} must be below max {axis} {}",
                        w.min[i], w.max[i]
                    ));
                }
            }
        }
        for t in &self.tools {
            if !(t.diameter.is_finite() && t.diameter > 0.0) {
                return Err(format!(
                    "tool {}: the diameter must be a positive number, got {}",
                    t.number, t.diameter
                ));
            }
        }
        match &self.link {
            LinkConfig::Grbl(g) if g.port.trim().is_empty() => Err("port must not be empty".into()),
            LinkConfig::Grbl(g) if g.baud == 0 => Err("baud must be above 0".into()),
            LinkConfig::SimGrbl(s) if !(s.time_scale.is_finite() && s.time_scale > 0.0) => Err(
                format!("time_scale must be a positive number, got {}", s.time_scale),
            ),
            LinkConfig::ModbusTcp(m) => m.settings().validate().map_err(|e| e.to_string()),
            LinkConfig::ModbusRtu(m) => m.settings().validate().map_err(|e| e.to_string()),
            LinkConfig::Sewing(g) if g.port.trim().is_empty() => {
                Err("port must not be empty".into())
            }
            LinkConfig::Sewing(g) if g.baud == 0 => Err("baud must be above 0".into()),
            LinkConfig::SimSewing(s) if !(s.time_scale.is_finite() && s.time_scale > 0.0) => Err(
                format!("time_scale must be a positive number, got {}", s.time_scale),
            ),
            LinkConfig::SimSewing(s) if s.spm == 0 => Err("spm must be above 0".into()),
            LinkConfig::SimSewing(s)
                if !(s.noise.is_finite() && (0.0..=0.1).contains(&s.noise)) =>
            {
                Err(format!("noise must be 0 to 0.1, got {}", s.noise))
            }
            _ => Ok(()),
        }
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

/// 1-based line and column of byte `offset` in `text`.
fn line_column(text: &str, offset: usize) -> (usize, usize) {
    let before = &text[..offset.min(text.len())];
    let line = before.matches('\n').count() + 1;
    let column = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
    (line, column)
}

/// The keys every machine table takes, whatever its link.
const COMMON_KEYS: [&str; 5] = ["name", "link", "work_area", "max_feed", "tools"];

impl<'de> Deserialize<'de> for MachineConfig {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_map(MachineVisitor)
    }
}

struct MachineVisitor;

impl<'de> Visitor<'de> for MachineVisitor {
    type Value = MachineConfig;

    fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.write_str("a [[machine]] table")
    }

    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<MachineConfig, A::Error> {
        let mut name: Option<String> = None;
        let mut work_area = None;
        let mut max_feed = None;
        let mut tools = Vec::new();
        let mut link_table = toml::Table::new();
        let link_keys = LinkConfig::all_keys();
        let who = |name: &Option<String>| match name {
            Some(n) => format!("machine `{n}`"),
            None => UNNAMED.to_string(),
        };
        while let Some(key) = map.next_key::<String>()? {
            let ctx = |e: String| format!("{}: key `{key}`: {e}", who(&name));
            match key.as_str() {
                "name" => name = Some(map.next_value_seed(Named(ctx, std::marker::PhantomData))?),
                "work_area" => {
                    work_area = Some(map.next_value_seed(Named(ctx, std::marker::PhantomData))?)
                }
                "max_feed" => {
                    max_feed = Some(map.next_value_seed(Named(ctx, std::marker::PhantomData))?)
                }
                "tools" => tools = map.next_value_seed(Named(ctx, std::marker::PhantomData))?,
                k if k == "link" || link_keys.contains(k) => {
                    let v: toml::Value =
                        map.next_value_seed(Named(ctx, std::marker::PhantomData))?;
                    link_table.insert(key, v);
                }
                _ => {
                    let mut known: Vec<&str> = COMMON_KEYS.to_vec();
                    known.extend(link_keys.iter());
                    let msg = format!(
                        "{}: unknown key `{key}` (a machine takes {})",
                        who(&name),
                        known.join(", ")
                    );
                    map.next_value_seed(Reject(msg))?;
                }
            }
        }
        let name = name.ok_or_else(|| de::Error::custom("a [[machine]] table has no `name`"))?;
        let kind = match link_table.get("link") {
            Some(toml::Value::String(s)) => s.clone(),
            Some(_) => {
                return Err(de::Error::custom(format!(
                "machine `{name}`: key `link` must be a string such as \"grbl\" or \"sim-grbl\""
            )))
            }
            None => {
                return Err(de::Error::custom(format!(
                    "machine `{name}` has no `link` (say link = \"grbl\" or link = \"sim-grbl\")"
                )))
            }
        };
        let link =
            LinkConfig::deserialize(toml::Value::Table(link_table.clone())).map_err(|e| {
                let message = e.message().trim().replace("field", "key");
                // name the key at fault: the one whose removal changes the complaint
                let culprit = link_table.keys().filter(|k| *k != "link").find(|k| {
                    let mut t = link_table.clone();
                    t.remove(*k);
                    match LinkConfig::deserialize(toml::Value::Table(t)) {
                        Ok(_) => true,
                        Err(e2) => e2.message().trim().replace("field", "key") != message,
                    }
                });
                let key = culprit.map(|k| format!("key `{k}`: ")).unwrap_or_default();
                de::Error::custom(format!(
                    "machine `{name}` (link = \"{kind}\"): {key}{message}"
                ))
            })?;
        Ok(MachineConfig {
            name,
            link,
            work_area,
            max_feed,
            tools,
        })
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

/// Refuses whatever value it is handed, so the error carries that value's place.
struct Reject(String);

impl<'de> DeserializeSeed<'de> for Reject {
    type Value = ();
    fn deserialize<D: Deserializer<'de>>(self, _d: D) -> Result<(), D::Error> {
        Err(de::Error::custom(self.0))
    }
}

/// The field names of a struct, as serde sees them (asks its Deserialize impl).
fn struct_fields<T: DeserializeOwned>() -> Vec<&'static str> {
    struct Probe<'a>(&'a mut Vec<&'static str>);
    #[derive(Debug)]
    struct Stop;
    impl std::fmt::Display for Stop {
        fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            f.write_str("probe")
        }
    }
    impl std::error::Error for Stop {}
    impl de::Error for Stop {
        fn custom<M: std::fmt::Display>(_: M) -> Self {
            Stop
        }
    }
    impl<'de> Deserializer<'de> for Probe<'_> {
        type Error = Stop;
        fn deserialize_any<V: Visitor<'de>>(self, _v: V) -> Result<V::Value, Stop> {
            Err(Stop)
        }
        fn deserialize_struct<V: Visitor<'de>>(
            self,
            _name: &'static str,
            fields: &'static [&'static str],
            _v: V,
        ) -> Result<V::Value, Stop> {
            self.0.extend_from_slice(fields);
            Err(Stop)
        }
        serde::forward_to_deserialize_any! {
            bool i8 i16 i32 i64 i128 u8 u16 u32 u64 u128 f32 f64 char str string bytes
            byte_buf option unit unit_struct newtype_struct seq tuple tuple_struct map enum
            identifier ignored_any
        }
    }
    let mut fields = Vec::new();
    let _ = T::deserialize(Probe(&mut fields));
    fields
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<Config, String> {
        Config::parse(text, Path::new("/etc/machlink/cell.toml")).map_err(|e| e.to_string())
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
        assert_eq!(
            c.machines[0].link,
            LinkConfig::Grbl(GrblLinkConfig {
                port: "/dev/ttyUSB0".into(),
                baud: 115_200,
                check_first: false,
                auto_unlock: true
            })
        );
        assert_eq!(c.machines[0].max_feed, Some(3000.0));
        assert_eq!(c.machines[0].tools[0].diameter, 3.0);
        assert_eq!(
            c.machines[1].link,
            LinkConfig::SimGrbl(SimGrblLinkConfig { time_scale: 20.0 })
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
            e.contains("machine `mill`") && e.contains("time_scale"),
            "{e}"
        );
        assert!(e.contains("line 1"), "{e}");
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
        assert!(e.contains("max_feed must be a positive number"), "{e}");
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
        assert_eq!(c.daemon.journal_every, 50);
        let names: Vec<&str> = c.machines.iter().map(|m| m.name.as_str()).collect();
        assert_eq!(names, ["router", "bench"]);
        assert_eq!(c.machines[0].tools.len(), 2);
    }

    #[test]
    fn struct_fields_lists_the_link_keys() {
        assert_eq!(
            struct_fields::<GrblLinkConfig>(),
            vec!["port", "baud", "check_first", "auto_unlock"]
        );
    }
}
