//! The link contract: how the daemon streams a program's units to a device, steers it, and
//! hears back, in typed words (states, events, errors) that no caller has to parse.

use crate::program::{Unit, Units};
use futures::future::BoxFuture;
use serde::{Deserialize, Serialize};
use tokio::sync::{mpsc, watch};

/// What the operator asks of a running stream.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Control {
    Run,
    /// Feed hold: the machine decelerates and waits; `Run` continues.
    Hold,
    /// Stop as soon as it is safe; what was acknowledged stays acknowledged.
    Cancel,
}

/// Why a machine waits for someone at it.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "reason", rename_all = "snake_case")]
pub enum OperatorReason {
    /// A sewing machine's thread broke: rethread, then resume.
    ThreadBreak,
    /// A safety door is open.
    Door,
    /// The program asks for another tool.
    ToolChange,
    /// The program stopped for a tool change and names the tool to load.
    LoadTool { number: u32, name: String },
    /// The program stopped itself (M0, M1) or the machine's own hold button was pressed.
    ProgramStop,
    /// A sewing machine stopped at a colour change of its pattern: load the thread of
    /// colour `colour` (1 is the pattern's first thread), then resume.
    ChangeThread { colour: u32 },
    /// Anything else the device names.
    Other { text: String },
}

impl std::fmt::Display for OperatorReason {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        match self {
            OperatorReason::ThreadBreak => f.write_str("thread break"),
            OperatorReason::Door => f.write_str("door open"),
            OperatorReason::ToolChange => f.write_str("tool change"),
            OperatorReason::LoadTool { number, name } if name.is_empty() => {
                write!(f, "load T{number}")
            }
            OperatorReason::LoadTool { number, name } => write!(f, "load T{number} ({name})"),
            OperatorReason::ProgramStop => f.write_str("program stop"),
            OperatorReason::ChangeThread { colour } => {
                write!(f, "change the thread to colour {colour}")
            }
            OperatorReason::Other { text } => f.write_str(text),
        }
    }
}

/// What a device is doing, in the daemon's words. Each kind maps its own states onto these;
/// the daemon reacts to these and never to a device's own state text.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "state", rename_all = "snake_case")]
pub enum DeviceState {
    /// Nothing reported yet.
    #[default]
    Unknown,
    Idle,
    Running,
    /// Held on the operator's request; resuming continues.
    Held,
    /// Stopped by a fault; needs clearing before it moves again.
    Alarm {
        /// The device's code, when it gives one (GRBL `ALARM:1`, a Modbus fault word).
        code: Option<u32>,
        text: String,
    },
    /// Waiting for someone at the machine.
    NeedsOperator {
        #[serde(flatten)]
        reason: OperatorReason,
    },
    /// The link is up but the device has answered nothing (no reply, no status report) for
    /// `silent_s` seconds: it may still be moving. After the kind's silence limit the link
    /// gives up (`LinkError::Timeout`) and the daemon reconnects.
    NotAnswering {
        silent_s: u64,
    },
    /// The link is down.
    Offline,
}

impl std::fmt::Display for DeviceState {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        match self {
            DeviceState::Unknown => f.write_str("unknown"),
            DeviceState::Idle => f.write_str("idle"),
            DeviceState::Running => f.write_str("running"),
            DeviceState::Held => f.write_str("held"),
            DeviceState::Alarm {
                code: Some(c),
                text,
            } => write!(f, "alarm {c}: {text}"),
            DeviceState::Alarm { code: None, text } => write!(f, "alarm: {text}"),
            DeviceState::NeedsOperator { reason } => write!(f, "needs operator: {reason}"),
            DeviceState::NotAnswering { silent_s } => write!(f, "not answering for {silent_s} s"),
            DeviceState::Offline => f.write_str("offline"),
        }
    }
}

impl MachineStatus {
    /// The status of a device silent since `since` (its last answer), standing where it was
    /// last seen.
    pub fn not_answering(last: &MachineStatus, silent: std::time::Duration) -> MachineStatus {
        MachineStatus {
            state: DeviceState::NotAnswering {
                silent_s: silent.as_secs(),
            },
            detail: format!(
                "no answer for {:.1} s (last: {})",
                silent.as_secs_f64(),
                last.state
            ),
            position: last.position,
            feed: 0.0,
        }
    }
}

/// A device's status as last reported.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MachineStatus {
    pub state: DeviceState,
    /// The device's own word for its state (GRBL `Hold:0`, a sewing machine's `ThreadBreak`),
    /// for people to read; nothing decides on it.
    pub detail: String,
    /// Work position, mm.
    pub position: [f64; 3],
    /// Current feed, mm/min.
    pub feed: f64,
}

/// What a link reports while it streams.
#[derive(Clone, Debug, PartialEq)]
pub enum LinkEvent {
    /// The device acknowledged units up to and including `unit` (0-based).
    Acked {
        unit: usize,
    },
    Status(MachineStatus),
    /// A message from the device worth showing the operator.
    Message(String),
}

/// How a stream ended without error.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StreamEnd {
    /// Every unit was acknowledged and the device finished moving.
    Completed,
    /// Stopped on request; `acked` units had been acknowledged.
    Cancelled { acked: usize },
}

/// Why a stream failed.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    #[error("cannot open {port}: {source}")]
    Open {
        port: String,
        #[source]
        source: std::io::Error,
    },
    /// The port is held by another program (or by a link closed a moment ago).
    #[error("{port} is in use by another program")]
    PortBusy { port: String },
    #[error("link I/O failed: {0}")]
    Io(#[from] std::io::Error),
    #[error("the device rejected unit {unit} ({text}): {reason}")]
    Rejected {
        unit: usize,
        text: String,
        reason: String,
    },
    /// The device stopped with an alarm; it keeps talking, and needs clearing.
    #[error("the device raised an alarm: {text}")]
    Alarm { code: Option<u32>, text: String },
    #[error("the device did not answer within {0:?}")]
    Timeout(std::time::Duration),
    #[error("the device broke protocol: {0}")]
    Protocol(String),
    /// The kind of machine cannot do what was asked; the text says what and why.
    #[error("{0}")]
    Unsupported(String),
    /// The journal could not record how far the program went, so streaming stopped rather
    /// than hand the device units a restart could not account for.
    #[error("cannot journal the program's progress: {0}")]
    Journal(String),
    /// The program's units could not be read where they are kept (the daemon's store).
    #[error("{0}")]
    Program(#[from] crate::program::UnitsError),
}

impl LinkError {
    /// Whether the device is still talking after this error, so the same link can serve the
    /// next job (a refused line, an alarm); otherwise the link is opened afresh.
    pub fn keeps_link(&self) -> bool {
        matches!(
            self,
            LinkError::Rejected { .. } | LinkError::Alarm { .. } | LinkError::Unsupported(_)
        )
    }

    /// Whether the link itself went away (a cable out, a port gone, a device that stopped
    /// answering): the job pauses and the daemon reconnects, rather than failing it.
    pub fn is_disconnect(&self) -> bool {
        matches!(
            self,
            LinkError::Io(_)
                | LinkError::Timeout(_)
                | LinkError::Open { .. }
                | LinkError::PortBusy { .. }
        )
    }

    /// Whether the device went silent (it stopped answering on a link that is still
    /// there), rather than its port going away.
    pub fn is_silence(&self) -> bool {
        match self {
            LinkError::Timeout(_) => true,
            LinkError::Io(e) => e.kind() == std::io::ErrorKind::TimedOut,
            _ => false,
        }
    }

    /// The refusal of an operation a kind does not have.
    pub fn unsupported(what: &str, why: &str) -> LinkError {
        LinkError::Unsupported(format!("{what} is not possible on this machine: {why}"))
    }
}

/// What the operator asks of a machine between jobs, at the machine.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "op", rename_all = "snake_case")]
pub enum Operation {
    /// Clear an alarm lock without homing (GRBL `$X`); the operator has made the machine safe.
    Unlock,
    /// Run the machine's homing cycle (GRBL `$H`).
    Home,
    /// Move by these distances (mm, relative to where the tool is) at `feed` mm/min
    /// (GRBL `$J=`).
    Jog {
        #[serde(default)]
        x: Option<f64>,
        #[serde(default)]
        y: Option<f64>,
        #[serde(default)]
        z: Option<f64>,
        feed: f64,
    },
}

impl Operation {
    /// The operation in the operator's words ("unlock", "home", "jog X10 F500").
    pub fn name(&self) -> String {
        match self {
            Operation::Unlock => "unlock".into(),
            Operation::Home => "home".into(),
            Operation::Jog { x, y, z, feed } => {
                let mut s = "jog".to_string();
                for (axis, v) in [('X', x), ('Y', y), ('Z', z)] {
                    if let Some(v) = v {
                        s.push_str(&format!(" {axis}{v}"));
                    }
                }
                s.push_str(&format!(" F{feed}"));
                s
            }
        }
    }

    /// Checks what a device would refuse anyway: a jog needs an axis and a feed above 0.
    pub fn check(&self) -> Result<(), String> {
        if let Operation::Jog { x, y, z, feed } = self {
            if x.is_none() && y.is_none() && z.is_none() {
                return Err("a jog needs a distance on at least one axis (--x, --y or --z)".into());
            }
            for v in [x, y, z].into_iter().flatten() {
                if !v.is_finite() {
                    return Err(format!("a jog distance must be a number, got {v}"));
                }
            }
            if !(feed.is_finite() && *feed > 0.0) {
                return Err(format!("a jog feed must be above 0 mm/min, got {feed}"));
            }
        }
        Ok(())
    }
}

/// The operator's overrides of a running program, in percent of what it programs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Overrides {
    /// Feed of cutting moves, 50 to 200.
    pub feed: u16,
    /// Spindle speed, 50 to 200.
    pub spindle: u16,
    /// Rapids: 25, 50 or 100.
    pub rapid: u16,
}

impl Default for Overrides {
    fn default() -> Self {
        Overrides {
            feed: 100,
            spindle: 100,
            rapid: 100,
        }
    }
}

impl Overrides {
    /// Checks the ranges every kind shares; one sentence naming the bad one.
    pub fn check(&self) -> Result<(), String> {
        if !(50..=200).contains(&self.feed) {
            return Err(format!(
                "the feed override must be 50 to 200 %, got {} %",
                self.feed
            ));
        }
        if !(50..=200).contains(&self.spindle) {
            return Err(format!(
                "the spindle override must be 50 to 200 %, got {} %",
                self.spindle
            ));
        }
        if ![25, 50, 100].contains(&self.rapid) {
            return Err(format!(
                "the rapid override must be 25, 50 or 100 %, got {} %",
                self.rapid
            ));
        }
        Ok(())
    }
}

/// How far a program went towards the device, as the daemon's journal knows it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Handed {
    /// Units the device acknowledged.
    pub acked: usize,
    /// Units handed to the device (their bytes left), for links that journal their writes.
    pub sent: usize,
    /// Units a write was about to hand over: `sent..sending` may or may not have reached the
    /// device (the daemon stopped between the journal and the write).
    pub sending: usize,
    /// The link dropped under a stream (a cable pulled, a port gone): bytes handed to the
    /// operating system may have been lost on the way, so `acked..sent` is in doubt too.
    /// False after a restart of the daemon, whose written bytes all reach the device.
    pub cut_off: bool,
    /// The operator said go on (a resume): a device found holding this program may be let
    /// go. False when the daemon only asks after a stop (a restart, a link that came back):
    /// then nothing that makes motion is sent (no cycle start, no new unit).
    #[serde(default)]
    pub go_on: bool,
}

/// Where a program stands on a device the daemon has just (re)connected to.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Reattach {
    /// The device is running (or holding) this program on its own: streaming from `acked`
    /// follows it, never restarting it or sending it a unit it has.
    Running { acked: usize },
    /// The device is not running it, and every unit before `next` is done: exactly where a
    /// resume continues.
    Stopped { next: usize },
    /// The device ran the whole program.
    Completed,
    /// The device cannot tell (it restarted, or holds another program): `next` is the best
    /// the journal knows, and `why` is for the operator, who decides where to resume.
    Unsure { next: usize, why: String },
}

/// Where a link writes, before a unit's bytes leave, how far it handed the program over: the
/// record a restarted daemon needs for devices that cannot be asked afterwards (GRBL).
pub trait SendJournal: Send {
    /// Units `..upto` are about to be handed to the device, `acked` of them acknowledged so
    /// far. Durable against a crash of the process when it returns.
    fn sending(&mut self, acked: usize, upto: usize) -> Result<(), String>;
    /// The device holds units `..upto`: their bytes left, or a reset dropped what was beyond.
    fn sent(&mut self, upto: usize) -> Result<(), String>;
}

/// What the daemon shows an operator before a stopped program goes on, and the link then does.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct ResumePlan {
    /// The unit the program continues at (0-based).
    pub from: usize,
    /// What the machine will do, in order, in the operator's words.
    pub steps: Vec<String>,
    /// Whether the machine moves before the program continues (the operator confirms).
    pub moves: bool,
}

/// A connection to one device that streams programs of units `U` (G-code lines, stitch
/// records, motion blocks, …) to it.
///
/// Only `stream` is required. The other operations have defaults that refuse with a reason
/// (or, for `reattach`, fall back on the journal), so a kind that cannot do one says so and
/// the daemon passes the sentence on; it never asks which kind it talks to.
///
/// The daemon streams through [`Link::stream_units`] and [`Link::reattach_units`], which
/// take the program wherever it is kept ([`Units`]: in memory, or page by page from the
/// store). A link whose programs can be long (GRBL: G-code files of millions of lines)
/// reads them there a page at a time; the defaults take every unit into memory first and
/// call `stream` and `reattach`, which suits devices that take the whole program at once.
pub trait Link<U: Unit>: Send {
    /// Streams `units` from unit `from` on, reporting progress on `events` and obeying
    /// `control`, until every unit is executed, the stream is cancelled, or it fails.
    fn stream<'a>(
        &'a mut self,
        units: &'a [U],
        from: usize,
        events: mpsc::UnboundedSender<LinkEvent>,
        control: watch::Receiver<Control>,
    ) -> BoxFuture<'a, Result<StreamEnd, LinkError>>;

    /// [`Link::stream`] of a program wherever it is kept. The default reads every unit into
    /// memory first.
    fn stream_units<'a>(
        &'a mut self,
        units: Units<'a, U>,
        from: usize,
        events: mpsc::UnboundedSender<LinkEvent>,
        control: watch::Receiver<Control>,
    ) -> BoxFuture<'a, Result<StreamEnd, LinkError>> {
        Box::pin(async move {
            let all = units.to_vec()?;
            self.stream(&all, from, events, control).await
        })
    }

    /// [`Link::reattach`] of a program wherever it is kept. The default reads every unit
    /// into memory first.
    fn reattach_units<'a>(
        &'a mut self,
        units: Units<'a, U>,
        handed: Handed,
        events: mpsc::UnboundedSender<LinkEvent>,
        control: watch::Receiver<Control>,
    ) -> BoxFuture<'a, Result<Reattach, LinkError>> {
        Box::pin(async move {
            let all = units.to_vec()?;
            self.reattach(&all, handed, events, control).await
        })
    }

    /// Asks the device what it is doing, without disturbing it (no reset, no motion): the
    /// daemon's first question after it (re)connects, and its poll while no job runs.
    fn inquire(&mut self) -> BoxFuture<'_, Result<MachineStatus, LinkError>> {
        Box::pin(async {
            Err(LinkError::unsupported(
                "asking the machine for its state",
                "its kind reports state only while a job runs",
            ))
        })
    }

    /// After the daemon restarted or the link came back: asks the device how far it got with
    /// `units` (which the journal says went out as far as `handed`), follows it while it runs
    /// what it already holds (reporting progress and obeying `control`), and says where the
    /// program stands. Never restarts the device or sends it a unit again. The default
    /// cannot ask, and says the journal's acknowledged count is the best it knows.
    fn reattach<'a>(
        &'a mut self,
        units: &'a [U],
        handed: Handed,
        events: mpsc::UnboundedSender<LinkEvent>,
        control: watch::Receiver<Control>,
    ) -> BoxFuture<'a, Result<Reattach, LinkError>> {
        let _ = (units, events, control);
        Box::pin(async move {
            Ok(Reattach::Unsure {
                next: handed.acked,
                why: "this kind of machine cannot say how far it got; the journal's last acknowledged unit is used".into(),
            })
        })
    }

    /// Carries out an operator's operation between jobs (unlock, home, jog); returns what
    /// the device said, for the operator.
    fn operate<'a>(&'a mut self, op: &'a Operation) -> BoxFuture<'a, Result<String, LinkError>> {
        Box::pin(async move {
            Err(LinkError::unsupported(
                &op.name(),
                "its kind has no such operation",
            ))
        })
    }

    /// Follows the operator's overrides in the streams that come: the daemon changes
    /// `overrides` while a job runs. Refused by kinds whose devices take none.
    fn follow_overrides(&mut self, overrides: watch::Receiver<Overrides>) -> Result<(), LinkError> {
        let _ = overrides;
        Err(LinkError::unsupported(
            "overriding feed, spindle or rapids",
            "its kind takes no overrides",
        ))
    }

    /// Hands the link the journal of the next stream, for links whose devices cannot be
    /// asked afterwards how far they got (GRBL); the others keep count on the device and
    /// drop it.
    fn keep_journal(&mut self, journal: Box<dyn SendJournal>) {
        let _ = journal;
    }
}
