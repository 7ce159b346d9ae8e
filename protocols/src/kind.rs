//! Machine kinds: the one seam every device plugs into.
//!
//! A kind (GRBL, Modbus TCP, a pattern sewing machine, …) says in one place: the keys its
//! `[[machine]]` table takes, which posts its machines run, how a G-code file becomes its
//! units, what to prepare when the daemon starts (a simulator, a check of the port), and how
//! its link opens. The daemon knows kinds only through a [`Registry`], looked up by the
//! table's `link = "…"`; docs/architecture.md has the recipe for adding one.

use crate::link::{
    Control, Handed, Link, LinkError, LinkEvent, MachineStatus, Operation, Overrides, Reattach,
    ResumePlan, SendJournal, StreamEnd,
};
use crate::post::{AnyPost, Post, PostError, PostFor};
use crate::program::{Program, Unit, UnitPages, Units};
use futures::future::BoxFuture;
use offset_core::Toolpath;
use serde::de::{self, DeserializeOwned, Deserializer, Visitor};
use serde::Serialize;
use std::any::Any;
use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Debug;
use std::sync::Arc;
use tokio::sync::{mpsc, watch};

/// A link being opened: what [`MachineKind::open`] returns.
pub type OpenLink<U> = BoxFuture<'static, Result<Box<dyn Link<U>>, LinkError>>;

/// One kind of machine.
pub trait MachineKind: Send + Sync + 'static {
    /// The keys of its `[[machine]]` table besides the common ones (name, link, work_area,
    /// max_feed, tools), as a serde struct that denies unknown fields.
    type Settings: Serialize + DeserializeOwned + Clone + Debug + Send + Sync + 'static;
    /// What its devices acknowledge one by one.
    type Unit: Unit;
    /// What [`MachineKind::start`] prepares for one machine (a simulator's handle), or `()`.
    type Device: Send + Sync + 'static;

    /// The value of `link = "…"` that names this kind.
    fn link(&self) -> &'static str;
    /// One line for docs and `machlink machines`.
    fn about(&self) -> &'static str;
    /// The keys of [`MachineKind::Settings`]; a hand-written Settings type (such as
    /// [`Joined`]) lists its own.
    fn keys(&self) -> Vec<&'static str> {
        struct_fields::<Self::Settings>()
    }
    /// The posts its machines run; the first is the one a job gets when it names none.
    fn posts(&self) -> Vec<PostFor<Self::Unit>>;
    /// Checks what serde cannot (a port that is not empty, a rate above 0); one sentence.
    fn check(&self, _settings: &Self::Settings) -> Result<(), String> {
        Ok(())
    }
    /// The units for a G-code program handed in as it is: its cleaned `lines`, and the same
    /// program read as moves (`moves`). None: this kind's machines take no G-code files.
    fn gcode_units(
        &self,
        _lines: &[String],
        _moves: &Toolpath,
    ) -> Option<Result<Vec<Self::Unit>, PostError>> {
        None
    }
    /// Whether [`MachineKind::gcode_units`] returns a G-code file's lines themselves, one unit
    /// per line, unchanged and without reading its moves (GRBL). The daemon then stores a long
    /// file as it streams in (its units as a JSON array of the lines) without building its
    /// moves or a second copy.
    fn gcode_lines_are_units(&self) -> bool {
        false
    }
    /// Whether this kind's machines run a G-code file as the moves it reads (Modbus, CANopen):
    /// the file is then read with [`crate::gcode_read::Reader::as_moves`], which refuses
    /// whatever the moves cannot carry, and each move is offered to
    /// [`MachineKind::gcode_move_refused`].
    fn gcode_runs_as_moves(&self) -> bool {
        false
    }
    /// For a kind that runs a G-code file as its moves: why its machines cannot run move `m`
    /// read from a line of the file (a program stop where the kind has none), in one
    /// sentence; None: they can.
    fn gcode_move_refused(&self, _m: &offset_core::toolpath::Move) -> Option<String> {
        None
    }
    /// The dialect whose G-codes this kind's controller reads from a G-code file line by
    /// line (GRBL), checked word by word before a job is stored; None: the file goes as its
    /// moves, so what the reader follows is what runs.
    fn gcode_dialect(&self) -> Option<crate::gcode::Dialect> {
        None
    }
    /// Prepares machine `machine` when the daemon starts: starts its simulator, warns of a
    /// port that is not there yet.
    fn start(
        &self,
        machine: &str,
        settings: &Self::Settings,
    ) -> BoxFuture<'static, std::io::Result<Self::Device>>;
    /// Opens the link to the machine.
    #[allow(clippy::type_complexity)]
    fn open(
        &self,
        machine: &str,
        settings: &Self::Settings,
        device: &Self::Device,
    ) -> OpenLink<Self::Unit>;
    /// What the machine does when a stopped program goes on at unit `from` (a resume after
    /// any interruption, or from a line the operator names): the steps the operator reads
    /// and confirms, and that the link then carries out. The default moves nothing: the
    /// device continues at unit `from` from where it stands. An error says why the program
    /// cannot go on there.
    fn resume_plan(
        &self,
        _settings: &Self::Settings,
        units: Units<'_, Self::Unit>,
        from: usize,
    ) -> Result<ResumePlan, String> {
        Ok(ResumePlan {
            from,
            steps: vec![match units.get(from).ok() {
                Some(u) => format!(
                    "the machine continues at unit {} ({}) from where it stands",
                    from + 1,
                    u.describe()
                ),
                None => "nothing is left to run".into(),
            }],
            moves: false,
        })
    }
    /// How long the machine takes to run `units`, for the ETA; None when the kind cannot
    /// tell.
    fn estimate(&self, _settings: &Self::Settings, _units: Units<'_, Self::Unit>) -> Option<f64> {
        None
    }
}

/// A link that streams [`Program`]s, whatever their units: what the daemon holds. It
/// carries every operation of [`Link`] with the program's units taken back as their type.
pub trait MachineLink: Send {
    fn stream<'a>(
        &'a mut self,
        program: &'a Program,
        from: usize,
        events: mpsc::UnboundedSender<LinkEvent>,
        control: watch::Receiver<Control>,
    ) -> BoxFuture<'a, Result<StreamEnd, LinkError>>;
    /// [`Link::inquire`].
    fn inquire(&mut self) -> BoxFuture<'_, Result<MachineStatus, LinkError>>;
    /// [`Link::reattach`].
    fn reattach<'a>(
        &'a mut self,
        program: &'a Program,
        handed: Handed,
        events: mpsc::UnboundedSender<LinkEvent>,
        control: watch::Receiver<Control>,
    ) -> BoxFuture<'a, Result<Reattach, LinkError>>;
    /// [`Link::operate`].
    fn operate<'a>(&'a mut self, op: &'a Operation) -> BoxFuture<'a, Result<String, LinkError>>;
    /// [`Link::follow_overrides`].
    fn follow_overrides(&mut self, overrides: watch::Receiver<Overrides>) -> Result<(), LinkError>;
    /// [`Link::keep_journal`].
    fn keep_journal(&mut self, journal: Box<dyn SendJournal>);
}

/// A kind's typed link behind [`MachineLink`]: the one place a program's units are taken
/// back as the type the link streams.
struct TypedLink<U>(Box<dyn Link<U>>);

fn foreign<T: Send + 'static>(program: &Program) -> BoxFuture<'static, Result<T, LinkError>> {
    let e = LinkError::Protocol(format!(
        "this machine cannot run a program made by the {} post",
        program.post()
    ));
    Box::pin(async move { Err(e) })
}

impl<U: Unit> MachineLink for TypedLink<U> {
    fn stream<'a>(
        &'a mut self,
        program: &'a Program,
        from: usize,
        events: mpsc::UnboundedSender<LinkEvent>,
        control: watch::Receiver<Control>,
    ) -> BoxFuture<'a, Result<StreamEnd, LinkError>> {
        match program.view::<U>() {
            Some(units) => self.0.stream_units(units, from, events, control),
            None => foreign(program),
        }
    }
    fn inquire(&mut self) -> BoxFuture<'_, Result<MachineStatus, LinkError>> {
        self.0.inquire()
    }
    fn reattach<'a>(
        &'a mut self,
        program: &'a Program,
        handed: Handed,
        events: mpsc::UnboundedSender<LinkEvent>,
        control: watch::Receiver<Control>,
    ) -> BoxFuture<'a, Result<Reattach, LinkError>> {
        match program.view::<U>() {
            Some(units) => self.0.reattach_units(units, handed, events, control),
            None => foreign(program),
        }
    }
    fn operate<'a>(&'a mut self, op: &'a Operation) -> BoxFuture<'a, Result<String, LinkError>> {
        self.0.operate(op)
    }
    fn follow_overrides(&mut self, overrides: watch::Receiver<Overrides>) -> Result<(), LinkError> {
        self.0.follow_overrides(overrides)
    }
    fn keep_journal(&mut self, journal: Box<dyn SendJournal>) {
        self.0.keep_journal(journal)
    }
}

/// A machine's settings as its kind parsed them, and as written (for listings).
#[derive(Clone)]
pub struct KindSettings {
    pub json: serde_json::Value,
    typed: Arc<dyn Any + Send + Sync>,
}

impl Debug for KindSettings {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        self.json.fmt(f)
    }
}

impl PartialEq for KindSettings {
    fn eq(&self, o: &KindSettings) -> bool {
        self.json == o.json
    }
}

impl KindSettings {
    /// The settings as the kind's own type.
    pub fn get<S: 'static>(&self) -> Option<&S> {
        self.typed.downcast_ref()
    }
}

/// What a kind prepared for one machine at start-up.
pub type Device = Arc<dyn Any + Send + Sync>;

/// A kind of any settings and unit type, as the registry holds it.
pub trait AnyKind: Send + Sync {
    fn link(&self) -> &'static str;
    fn about(&self) -> &'static str;
    /// The keys its table takes besides the common ones.
    fn keys(&self) -> Vec<&'static str>;
    /// Parses and checks a machine's settings (its table without the common keys).
    fn settings(&self, table: serde_json::Value) -> Result<KindSettings, String>;
    /// The posts it runs, the default first.
    fn posts(&self) -> Vec<Arc<dyn AnyPost>>;
    /// A stored program's units read back.
    fn decode(&self, post: &str, units_json: &str) -> Result<Program, serde_json::Error>;
    /// A stored program whose units stay where they are kept, read back page by page.
    fn decode_pages(&self, post: &str, pages: Arc<dyn UnitPages>) -> Program;
    /// A G-code program handed in as it is; None when the kind takes none.
    fn gcode(&self, lines: &[String], moves: &Toolpath) -> Option<Result<Program, PostError>>;
    /// See [`MachineKind::gcode_lines_are_units`].
    fn gcode_lines_are_units(&self) -> bool;
    /// See [`MachineKind::gcode_dialect`].
    fn gcode_dialect(&self) -> Option<crate::gcode::Dialect>;
    /// See [`MachineKind::gcode_runs_as_moves`].
    fn gcode_runs_as_moves(&self) -> bool;
    /// See [`MachineKind::gcode_move_refused`].
    fn gcode_move_refused(&self, m: &offset_core::toolpath::Move) -> Option<String>;
    fn start(
        &self,
        machine: &str,
        settings: &KindSettings,
    ) -> BoxFuture<'static, std::io::Result<Device>>;
    fn open(
        &self,
        machine: &str,
        settings: &KindSettings,
        device: &Device,
    ) -> BoxFuture<'static, Result<Box<dyn MachineLink>, LinkError>>;
    /// [`MachineKind::resume_plan`] for a stored program.
    fn resume_plan(
        &self,
        settings: &KindSettings,
        program: &Program,
        from: usize,
    ) -> Result<ResumePlan, String>;
    /// [`MachineKind::estimate`] for a program, seconds.
    fn estimate(&self, settings: &KindSettings, program: &Program) -> Option<f64>;
}

/// A start that prepares nothing beyond what `f` does now.
pub fn started<T: Send + 'static>(v: T) -> BoxFuture<'static, std::io::Result<T>> {
    Box::pin(async move { Ok(v) })
}

/// The name a program made from a G-code file as it is carries.
pub const GCODE_FILE: &str = "gcode-file";

/// A post whose unit type is a kind's, as an [`AnyPost`].
struct ErasedPost<U>(PostFor<U>);

impl<U: Unit> AnyPost for ErasedPost<U> {
    fn name(&self) -> &'static str {
        self.0.name()
    }
    fn about(&self) -> &'static str {
        self.0.about()
    }
    fn extension(&self) -> &'static str {
        self.0.extension()
    }
    fn program(&self, tp: &Toolpath) -> Result<Program, PostError> {
        Ok(Program::new(self.0.name(), self.0.units(tp)?))
    }
    fn file(&self, program: &Program, label: &str) -> Result<Vec<u8>, PostError> {
        // a program in memory (what a post just made) is written from its own units; one
        // read page by page is gathered first
        if let Some(units) = program.units::<U>() {
            return self.0.file(units, label);
        }
        let units = program.view::<U>().ok_or_else(|| {
            PostError::new(
                self.0.name(),
                format!(
                    "a program made by the {} post cannot be written as a {} file",
                    program.post(),
                    self.0.name()
                ),
            )
        })?;
        let units = units
            .to_vec()
            .map_err(|e| PostError::new(self.0.name(), e.to_string()))?;
        self.0.file(&units, label)
    }
}

fn mismatch<T>(kind: &str) -> Result<T, std::io::Error> {
    Err(std::io::Error::other(format!(
        "the settings handed to the {kind} kind are not its own"
    )))
}

impl<K: MachineKind> AnyKind for K {
    fn link(&self) -> &'static str {
        MachineKind::link(self)
    }
    fn about(&self) -> &'static str {
        MachineKind::about(self)
    }
    fn keys(&self) -> Vec<&'static str> {
        MachineKind::keys(self)
    }
    fn settings(&self, table: serde_json::Value) -> Result<KindSettings, String> {
        let typed: K::Settings = serde_json::from_value(table).map_err(|e| {
            // serde_json adds " at line 0 column 0" to errors from values
            let m = e.to_string();
            m.trim_end_matches(" at line 0 column 0")
                .replace("field", "key")
        })?;
        self.check(&typed)?;
        let json = serde_json::to_value(&typed).map_err(|e| e.to_string())?;
        Ok(KindSettings {
            json,
            typed: Arc::new(typed),
        })
    }
    fn posts(&self) -> Vec<Arc<dyn AnyPost>> {
        MachineKind::posts(self)
            .into_iter()
            .map(|p| Arc::new(ErasedPost(p)) as Arc<dyn AnyPost>)
            .collect()
    }
    fn decode(&self, post: &str, units_json: &str) -> Result<Program, serde_json::Error> {
        Program::from_json::<K::Unit>(post, units_json)
    }
    fn decode_pages(&self, post: &str, pages: Arc<dyn UnitPages>) -> Program {
        Program::paged::<K::Unit>(post, pages)
    }
    fn gcode(&self, lines: &[String], moves: &Toolpath) -> Option<Result<Program, PostError>> {
        self.gcode_units(lines, moves)
            .map(|r| r.map(|units| Program::new(GCODE_FILE, units)))
    }
    fn gcode_lines_are_units(&self) -> bool {
        MachineKind::gcode_lines_are_units(self)
    }
    fn gcode_dialect(&self) -> Option<crate::gcode::Dialect> {
        MachineKind::gcode_dialect(self)
    }
    fn gcode_runs_as_moves(&self) -> bool {
        MachineKind::gcode_runs_as_moves(self)
    }
    fn gcode_move_refused(&self, m: &offset_core::toolpath::Move) -> Option<String> {
        MachineKind::gcode_move_refused(self, m)
    }
    fn start(
        &self,
        machine: &str,
        settings: &KindSettings,
    ) -> BoxFuture<'static, std::io::Result<Device>> {
        let Some(s) = settings.get::<K::Settings>() else {
            let e = mismatch::<()>(MachineKind::link(self));
            return Box::pin(async move { e.map(|()| Arc::new(()) as Device) });
        };
        let start = MachineKind::start(self, machine, s);
        Box::pin(async move { Ok(Arc::new(start.await?) as Device) })
    }
    fn open(
        &self,
        machine: &str,
        settings: &KindSettings,
        device: &Device,
    ) -> BoxFuture<'static, Result<Box<dyn MachineLink>, LinkError>> {
        let (Some(s), Some(d)) = (
            settings.get::<K::Settings>(),
            device.downcast_ref::<K::Device>(),
        ) else {
            let e = mismatch::<()>(MachineKind::link(self)).unwrap_err();
            return Box::pin(async move { Err(LinkError::Io(e)) });
        };
        let open = MachineKind::open(self, machine, s, d);
        Box::pin(async move {
            let link = open.await?;
            Ok(Box::new(TypedLink(link)) as Box<dyn MachineLink>)
        })
    }
    fn resume_plan(
        &self,
        settings: &KindSettings,
        program: &Program,
        from: usize,
    ) -> Result<ResumePlan, String> {
        let s = settings.get::<K::Settings>().ok_or_else(|| {
            format!(
                "the settings handed to the {} kind are not its own",
                MachineKind::link(self)
            )
        })?;
        let units = program.view::<K::Unit>().ok_or_else(|| {
            format!(
                "this machine cannot run a program made by the {} post",
                program.post()
            )
        })?;
        MachineKind::resume_plan(self, s, units, from)
    }
    fn estimate(&self, settings: &KindSettings, program: &Program) -> Option<f64> {
        let s = settings.get::<K::Settings>()?;
        let units = program.view::<K::Unit>()?;
        MachineKind::estimate(self, s, units).filter(|t| t.is_finite() && *t >= 0.0)
    }
}

/// Every kind and post the daemon knows, by name.
#[derive(Clone, Default)]
pub struct Registry {
    kinds: BTreeMap<&'static str, Arc<dyn AnyKind>>,
    posts: BTreeMap<&'static str, Arc<dyn AnyPost>>,
}

impl Registry {
    pub fn new() -> Registry {
        Registry::default()
    }

    /// Adds a kind, and the posts it runs.
    pub fn add_kind<K: MachineKind>(&mut self, kind: K) -> &mut Registry {
        for p in AnyKind::posts(&kind) {
            self.posts.entry(p.name()).or_insert(p);
        }
        self.kinds.insert(MachineKind::link(&kind), Arc::new(kind));
        self
    }

    /// Adds a post no kind runs (written by `plan` only).
    pub fn add_post<P: Post>(&mut self, post: P) -> &mut Registry {
        self.posts.insert(Post::name(&post), Arc::new(post));
        self
    }

    /// The kind named by `link = "…"`.
    pub fn kind(&self, link: &str) -> Option<&Arc<dyn AnyKind>> {
        self.kinds.get(link)
    }

    /// The post named by `--post`.
    pub fn post(&self, name: &str) -> Option<&Arc<dyn AnyPost>> {
        self.posts.get(name)
    }

    pub fn kinds(&self) -> impl Iterator<Item = &Arc<dyn AnyKind>> {
        self.kinds.values()
    }

    pub fn posts(&self) -> impl Iterator<Item = &Arc<dyn AnyPost>> {
        self.posts.values()
    }

    /// The link names, for messages ("grbl, modbus-tcp, …").
    pub fn link_names(&self) -> Vec<&'static str> {
        self.kinds.keys().copied().collect()
    }

    /// The post names, for messages.
    pub fn post_names(&self) -> Vec<&'static str> {
        self.posts.keys().copied().collect()
    }

    /// Every key some kind takes (to tell an unknown key from one of another kind).
    pub fn all_keys(&self) -> BTreeSet<&'static str> {
        self.kinds.values().flat_map(|k| k.keys()).collect()
    }
}

/// The field names of a struct, as serde sees them (asks its Deserialize impl).
pub fn struct_fields<T: DeserializeOwned>() -> Vec<&'static str> {
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

/// Settings made of two tables written as one: a transport's own keys (`T`) and keys shared
/// with other kinds (`C`), e.g. Modbus TCP's host and port beside the Modbus ring's unit,
/// word order and timeouts. Each part denies keys it does not know; a key neither knows is
/// refused naming the keys of both.
#[derive(Clone, Debug, PartialEq)]
pub struct Joined<T, C> {
    pub own: T,
    pub common: C,
}

impl<T: Serialize, C: Serialize> Serialize for Joined<T, C> {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::{Error, SerializeMap};
        let mut all = serde_json::Map::new();
        for part in [
            serde_json::to_value(&self.own),
            serde_json::to_value(&self.common),
        ] {
            match part.map_err(S::Error::custom)? {
                serde_json::Value::Object(m) => all.extend(m),
                _ => return Err(S::Error::custom("settings must be tables")),
            }
        }
        let mut map = s.serialize_map(Some(all.len()))?;
        for (k, v) in &all {
            map.serialize_entry(k, v)?;
        }
        map.end()
    }
}

impl<T: DeserializeOwned, C: DeserializeOwned> Joined<T, C> {
    /// The keys of both parts (a kind with joined settings returns these from `keys`).
    pub fn keys() -> Vec<&'static str> {
        let mut keys = struct_fields::<T>();
        keys.extend(struct_fields::<C>());
        keys
    }
}

impl<'de, T: DeserializeOwned, C: DeserializeOwned> serde::Deserialize<'de> for Joined<T, C> {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let own_keys = struct_fields::<T>();
        let common_keys = struct_fields::<C>();
        let all_keys = Self::keys();
        struct MapOnly;
        impl<'de> Visitor<'de> for MapOnly {
            type Value = serde_json::Map<String, serde_json::Value>;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a table of settings")
            }
            fn visit_map<A: de::MapAccess<'de>>(self, mut m: A) -> Result<Self::Value, A::Error> {
                let mut out = serde_json::Map::new();
                while let Some((k, v)) = m.next_entry::<String, serde_json::Value>()? {
                    out.insert(k, v);
                }
                Ok(out)
            }
        }
        let table = d.deserialize_map(MapOnly)?;
        let (mut own, mut common) = (serde_json::Map::new(), serde_json::Map::new());
        for (k, v) in table {
            if common_keys.contains(&k.as_str()) {
                common.insert(k, v);
            } else if own_keys.contains(&k.as_str()) {
                own.insert(k, v);
            } else {
                return Err(de::Error::custom(format!(
                    "unknown key `{k}`, expected one of {}",
                    all_keys
                        .iter()
                        .map(|k| format!("`{k}`"))
                        .collect::<Vec<_>>()
                        .join(", ")
                )));
            }
        }
        let own = T::deserialize(serde_json::Value::Object(own)).map_err(de::Error::custom)?;
        let common =
            C::deserialize(serde_json::Value::Object(common)).map_err(de::Error::custom)?;
        Ok(Joined { own, common })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Clone, Debug, PartialEq, Serialize, serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    struct Own {
        host: String,
    }
    #[derive(Clone, Debug, PartialEq, Serialize, serde::Deserialize)]
    #[serde(deny_unknown_fields)]
    struct Common {
        #[serde(default)]
        unit: u8,
    }

    #[test]
    fn joined_settings_split_their_keys_and_name_both_parts() {
        assert_eq!(Joined::<Own, Common>::keys(), ["host", "unit"]);
        let j: Joined<Own, Common> =
            serde_json::from_value(serde_json::json!({"host": "plc", "unit": 3})).unwrap();
        assert_eq!(j.own.host, "plc");
        assert_eq!(j.common.unit, 3);
        assert_eq!(
            serde_json::to_value(&j).unwrap(),
            serde_json::json!({"host": "plc", "unit": 3})
        );
        let e = serde_json::from_value::<Joined<Own, Common>>(
            serde_json::json!({"host": "plc", "baud": 3}),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("`baud`") && e.contains("`host`, `unit`"), "{e}");
        let e = serde_json::from_value::<Joined<Own, Common>>(serde_json::json!({"unit": 3}))
            .unwrap_err()
            .to_string();
        assert!(e.contains("host"), "{e}");
    }
}
