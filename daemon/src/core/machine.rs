//! One `[[machine]]` table of the config file, parsed and checked here: the keys every
//! machine takes (name, link, work area, feed limit, M-codes, tools) and its kind's own keys,
//! read by the kind from the registry. Errors are a message and the place in the file it is
//! about; `config` turns the place into a line and column.

use machlink_protocols::kind::{AnyKind, KindSettings, Registry};
use serde::de::{self, DeserializeSeed, Deserializer, MapAccess, Visitor};
use serde::{Deserialize, Serialize};
use std::collections::BTreeSet;
use std::sync::Arc;

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
    /// The recipe a job for this machine gets when it names no operation (`recipe =
    /// "sign.toml"`, relative to the config file; read and checked when the config is).
    pub recipe: Option<std::path::PathBuf>,
    /// Measure each tool's length on the touch plate after it is loaded (`probe = true`).
    pub probe: bool,
    /// Where the touch plate lies and how to probe it (`touch_plate = { x = …, y = … }`).
    pub touch_plate: Option<TouchPlate>,
}

/// The touch plate of a machine that probes its tools' lengths: it lies on the stock top at
/// (`x`, `y`) in work coordinates, `thickness` mm thick. The probe starts `clear` mm above
/// the work's zero and goes down at most `travel` mm at `feed` mm/min.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TouchPlate {
    pub x: f64,
    pub y: f64,
    #[serde(default)]
    pub thickness: f64,
    #[serde(default = "default_probe_feed")]
    pub feed: f64,
    #[serde(default = "default_probe_clear")]
    pub clear: f64,
    #[serde(default = "default_probe_travel")]
    pub travel: f64,
}

/// 100 mm/min: slow enough that the tool stops within a few micrometres of the touch.
fn default_probe_feed() -> f64 {
    100.0
}
fn default_probe_clear() -> f64 {
    10.0
}
fn default_probe_travel() -> f64 {
    30.0
}

impl TouchPlate {
    /// The probe move of this plate (offset_core's `Move::ProbeToolLength`).
    pub fn probe_move(&self) -> offset_core::Move {
        offset_core::Move::ProbeToolLength {
            at: offset_core::geom::Point::new(self.x, self.y),
            clear: self.clear,
            lowest: self.clear - self.travel,
            feed: self.feed,
            thickness: self.thickness,
        }
    }

    /// Problems with the plate's numbers, in one sentence naming the key.
    fn check(&self, max_feed: Option<f64>, area: Option<&WorkArea>) -> Result<(), String> {
        let p = self;
        for (k, v) in [
            ("x", p.x),
            ("y", p.y),
            ("thickness", p.thickness),
            ("feed", p.feed),
            ("clear", p.clear),
            ("travel", p.travel),
        ] {
            if !v.is_finite() {
                return Err(format!("key `touch_plate`: {k} must be a number, got {v}"));
            }
        }
        if p.thickness < 0.0 {
            return Err(format!(
                "key `touch_plate`: thickness must be 0 or more, got {}",
                p.thickness
            ));
        }
        if p.feed <= 0.0 || max_feed.is_some_and(|m| p.feed > m) {
            return Err(format!(
                "key `touch_plate`: feed must be a positive number{}, got {}",
                max_feed.map_or(String::new(), |m| format!(" up to max_feed {m}")),
                p.feed
            ));
        }
        if p.clear <= p.thickness {
            return Err(format!(
                "key `touch_plate`: clear ({}) must be above the plate's top (thickness {})",
                p.clear, p.thickness
            ));
        }
        if p.travel <= p.clear - p.thickness {
            return Err(format!(
                "key `touch_plate`: travel ({}) must reach below the plate's top, more than clear − thickness = {}",
                p.travel,
                p.clear - p.thickness
            ));
        }
        if let Some(w) = area {
            let inside = |k: usize, v: f64| v >= w.min[k] && v <= w.max[k];
            if !(inside(0, p.x) && inside(1, p.y) && inside(2, p.clear)) {
                return Err(format!(
                    "key `touch_plate`: the plate at ({}, {}) probed from Z {} lies outside the work_area",
                    p.x, p.y, p.clear
                ));
            }
        }
        Ok(())
    }
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
            .field("recipe", &self.recipe)
            .field("probe", &self.probe)
            .field("touch_plate", &self.touch_plate)
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
            && self.recipe == o.recipe
            && self.probe == o.probe
            && self.touch_plate == o.touch_plate
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
            recipe: None,
            probe: false,
            touch_plate: None,
        })
    }
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
        if self.probe {
            if !self.kind.gcode_lines_are_units() {
                return Err(format!(
                    "key `probe`: a link = \"{}\" machine runs no G-code, and the tool-length probe is G38.2 then G10 L20; leave probe out",
                    self.link
                ));
            }
            let Some(p) = &self.touch_plate else {
                return Err(
                    "key `probe`: probe = true needs the touch plate: touch_plate = { x = …, y = …, thickness = … }"
                        .into(),
                );
            };
            p.check(self.max_feed, self.work_area.as_ref())?;
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
pub const UNNAMED: &str = "a [[machine]] table";

/// The keys every machine table takes, whatever its link.
const COMMON_KEYS: [&str; 9] = [
    "name",
    "link",
    "work_area",
    "max_feed",
    "allowed_m_codes",
    "tools",
    "recipe",
    "probe",
    "touch_plate",
];

/// A `[[machine]]` table as written: the common keys typed, every other key kept with its
/// place in the file for the kind to read (and for errors to point at).
pub struct RawMachine {
    name: String,
    link: toml::Spanned<toml::Value>,
    work_area: Option<WorkArea>,
    max_feed: Option<f64>,
    allowed_m_codes: Option<Vec<u32>>,
    tools: Vec<ToolConfig>,
    recipe: Option<std::path::PathBuf>,
    probe: bool,
    touch_plate: Option<TouchPlate>,
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
        let mut recipe = None;
        let mut probe = false;
        let mut touch_plate = None;
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
                "recipe" => {
                    recipe = Some(map.next_value_seed(Named(ctx, std::marker::PhantomData))?)
                }
                "probe" => probe = map.next_value_seed(Named(ctx, std::marker::PhantomData))?,
                "touch_plate" => {
                    touch_plate = Some(map.next_value_seed(Named(ctx, std::marker::PhantomData))?)
                }
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
            recipe,
            probe,
            touch_plate,
            others,
        })
    }
}

impl RawMachine {
    /// The machine, its kind found in `registry` and its kind's keys read by the kind; an
    /// error is a message and the place in the file it is about.
    pub fn resolve(
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
            recipe: self.recipe,
            probe: self.probe,
            touch_plate: self.touch_plate,
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
