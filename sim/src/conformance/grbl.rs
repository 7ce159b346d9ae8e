//! The GRBL 1.1 controller's state table (docs/grbl.md): every line and real-time byte a host sends in every state, with the answer and the next state a controller gives, and a driver that checks one cell on a controller over its serial line.

use std::time::Duration;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::time::Instant;

const BANNER: &str = "\r\nGrbl 1.1h ['$' for help]\r\n";
const UNLOCK: &str = "[MSG:'$H'|'$X' to unlock]\r\n";

/// The states of the table's columns. An alarm raised by the controller itself (a limit,
/// an injected fault: `ALARM:n` then `[MSG:Reset to continue]`) ignores every line until a
/// soft reset, after which it is the ordinary, locked alarm that `$X` unlocks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Column {
    Idle,
    Run,
    Hold,
    Alarm,
    AlarmBeforeReset,
    Check,
}

pub const COLUMNS: [Column; 6] = [
    Column::Idle,
    Column::Run,
    Column::Hold,
    Column::Alarm,
    Column::AlarmBeforeReset,
    Column::Check,
];

impl Column {
    /// The word status reports start with.
    fn word(self) -> &'static str {
        match self {
            Column::Idle => "Idle",
            Column::Run => "Run",
            Column::Hold => "Hold",
            Column::Alarm | Column::AlarmBeforeReset => "Alarm",
            Column::Check => "Check",
        }
    }
    fn heading(self) -> &'static str {
        match self {
            Column::Idle => "Idle",
            Column::Run => "Run",
            Column::Hold => "Hold",
            Column::Alarm => "Alarm (locked)",
            Column::AlarmBeforeReset => "Alarm (raised, before a reset)",
            Column::Check => "Check",
        }
    }
}

/// The requests of the table's rows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Ask {
    Motion,
    Rejected,
    TooLong,
    Status,
    FeedHold,
    CycleStart,
    Reset,
    Unlock,
    CheckMode,
    Home,
    Settings,
    Info,
    SetSetting,
}

pub const ASKS: [Ask; 13] = [
    Ask::Motion,
    Ask::Rejected,
    Ask::TooLong,
    Ask::Status,
    Ask::FeedHold,
    Ask::CycleStart,
    Ask::Reset,
    Ask::Unlock,
    Ask::CheckMode,
    Ask::Home,
    Ask::Settings,
    Ask::Info,
    Ask::SetSetting,
];

impl Ask {
    pub fn text(self) -> &'static str {
        match self {
            Ask::Motion => "a motion line, e.g. `G1 X1 F100`",
            Ask::Rejected => "a line GRBL refuses, e.g. `M6 T2`",
            Ask::TooLong => "a line of more than 79 characters",
            Ask::Status => "`?` (real time)",
            Ask::FeedHold => "`!` (real time)",
            Ask::CycleStart => "`~` (real time)",
            Ask::Reset => "0x18 soft reset (real time)",
            Ask::Unlock => "`$X`",
            Ask::CheckMode => "`$C`",
            Ask::Home => "`$H`",
            Ask::Settings => "`$$`",
            Ask::Info => "`$I`",
            Ask::SetSetting => "`$110=800`",
        }
    }
    fn bytes(self) -> Vec<u8> {
        match self {
            Ask::Motion => b"G1 X1 F100\n".to_vec(),
            Ask::Rejected => b"M6 T2\n".to_vec(),
            Ask::TooLong => {
                let mut l = b"G1 X1".to_vec();
                l.extend(std::iter::repeat_n(b'0', 80));
                l.push(b'\n');
                l
            }
            Ask::Status => b"?".to_vec(),
            Ask::FeedHold => b"!".to_vec(),
            Ask::CycleStart => b"~".to_vec(),
            Ask::Reset => vec![0x18],
            Ask::Unlock => b"$X\n".to_vec(),
            Ask::CheckMode => b"$C\n".to_vec(),
            Ask::Home => b"$H\n".to_vec(),
            Ask::Settings => b"$$\n".to_vec(),
            Ask::Info => b"$I\n".to_vec(),
            Ask::SetSetting => b"$110=800\n".to_vec(),
        }
    }
}

/// What the controller answers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Answer {
    Ok,
    Error(u8),
    /// A status report `<…>`.
    Report,
    /// The banner.
    Banner,
    /// The banner and `[MSG:'$H'|'$X' to unlock]`.
    BannerLocked,
    /// `ALARM:3`, the banner, `[MSG:'$H'|'$X' to unlock]`: reset while moving.
    ResetInMotion,
    /// `[MSG:Caution: Unlocked]`, `ok`.
    Unlocked,
    /// `[MSG:Enabled]`, `ok`.
    CheckOn,
    /// `[MSG:Disabled]`, `ok`, the banner: leaving check mode resets.
    CheckOff,
    /// `$n=v` lines, `ok`.
    SettingsList,
    /// `[VER:…]`, `[OPT:…]`, `ok`.
    Build,
    /// Nothing.
    Silence,
}

/// One cell of this table.
pub type Cell = super::Cell<Answer, Column>;
use super::cell_of;

/// The table: what a GRBL 1.1 controller does on `ask` in `column`.
pub fn cell(ask: Ask, column: Column) -> Cell {
    use Answer as A;
    use Column as C;
    let busy = matches!(column, C::Run | C::Hold);
    match (ask, column) {
        (Ask::Status, _) => cell_of(A::Report, None),
        (Ask::FeedHold, C::Idle | C::Run) => cell_of(A::Silence, Some(C::Hold)),
        (Ask::CycleStart, C::Hold) => cell_of(A::Silence, Some(C::Run)),
        (Ask::FeedHold | Ask::CycleStart, _) => cell_of(A::Silence, None),
        (Ask::Reset, C::Run) => cell_of(A::ResetInMotion, Some(C::Alarm)),
        (Ask::Reset, C::Alarm | C::AlarmBeforeReset) => cell_of(A::BannerLocked, Some(C::Alarm)),
        (Ask::Reset, _) => cell_of(A::Banner, Some(C::Idle)),
        // every line waits unread until the reset (which throws it away)
        (_, C::AlarmBeforeReset) => cell_of(A::Silence, None),
        (Ask::TooLong, _) => cell_of(A::Error(11), None),
        (Ask::Motion | Ask::Rejected, C::Alarm) => cell_of(A::Error(9), None),
        (Ask::Motion, C::Idle) => cell_of(A::Ok, Some(C::Run)),
        (Ask::Motion, _) => cell_of(A::Ok, None),
        (Ask::Rejected, _) => cell_of(A::Error(20), None),
        (Ask::Unlock, C::Alarm) => cell_of(A::Unlocked, Some(C::Idle)),
        (Ask::Unlock, _) => cell_of(A::Ok, None),
        (Ask::CheckMode, C::Idle) => cell_of(A::CheckOn, Some(C::Check)),
        (Ask::CheckMode, C::Check) => cell_of(A::CheckOff, Some(C::Idle)),
        (Ask::CheckMode, _) => cell_of(A::Error(8), None),
        (Ask::Home, _) => cell_of(A::Error(5), None),
        (Ask::Settings | Ask::SetSetting, _) if busy => cell_of(A::Error(8), None),
        (Ask::Settings, _) => cell_of(A::SettingsList, None),
        (Ask::SetSetting, _) => cell_of(A::Ok, None),
        (Ask::Info, _) => cell_of(A::Build, None),
    }
}

fn answer_text(a: Answer) -> String {
    match a {
        Answer::Ok => "`ok`".into(),
        Answer::Error(n) => format!("`error:{n}`"),
        Answer::Report => "report".into(),
        Answer::Banner => "banner".into(),
        Answer::BannerLocked => "banner, unlock msg".into(),
        Answer::ResetInMotion => "`ALARM:3`, banner, unlock msg".into(),
        Answer::Unlocked => "`[MSG:Caution: Unlocked]` `ok`".into(),
        Answer::CheckOn => "`[MSG:Enabled]` `ok`".into(),
        Answer::CheckOff => "`[MSG:Disabled]` `ok`, banner".into(),
        Answer::SettingsList => "`$n=v` lines, `ok`".into(),
        Answer::Build => "`[VER:…]` `[OPT:…]` `ok`".into(),
        Answer::Silence => "–".into(),
    }
}

fn cell_text(c: Cell) -> String {
    let a = answer_text(c.answer);
    match c.next {
        Some(n) => format!("{a} → {}", n.heading()),
        None => a,
    }
}

/// The state table as docs/grbl.md carries it.
pub fn markdown_table() -> String {
    super::markdown(
        "sent \\ state",
        &ASKS,
        &COLUMNS,
        |a| a.text().to_string(),
        |c| c.heading().to_string(),
        |a, c| cell_text(cell(a, c)),
    )
}

struct Line<S> {
    io: S,
}

impl<S: AsyncRead + AsyncWrite + Unpin> Line<S> {
    async fn send(&mut self, bytes: &[u8]) -> Result<(), String> {
        self.io
            .write_all(bytes)
            .await
            .map_err(|e| format!("writing: {e}"))?;
        self.io.flush().await.map_err(|e| format!("writing: {e}"))
    }
    /// What the controller says until it has been quiet for `quiet` (at most 3 s).
    async fn said(&mut self, quiet: Duration) -> Result<String, String> {
        let give_up = Instant::now() + Duration::from_secs(3);
        let mut out = Vec::new();
        let mut buf = [0u8; 1024];
        while Instant::now() < give_up {
            match tokio::time::timeout(quiet, self.io.read(&mut buf)).await {
                Err(_) => break,
                Ok(Ok(0)) => return Err("the controller closed the line".into()),
                Ok(Ok(n)) => out.extend_from_slice(&buf[..n]),
                Ok(Err(e)) => return Err(format!("reading: {e}")),
            }
        }
        Ok(String::from_utf8_lossy(&out).into_owned())
    }
    /// What the controller says until `marker` has come (within `within`) and it has then
    /// been quiet for 80 ms: for the power-up banner, which a loaded machine may print
    /// long after the port opened. The marker is looked for after every read, so the wait
    /// ends as soon as it is in.
    async fn said_through(&mut self, marker: &str, within: Duration) -> Result<String, String> {
        let give_up = Instant::now() + within;
        let mut out = Vec::new();
        let mut buf = [0u8; 1024];
        while !String::from_utf8_lossy(&out).contains(marker) {
            let left = give_up.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(format!(
                    "no {marker:?} within {within:?} of power-up; heard {:?}",
                    String::from_utf8_lossy(&out)
                ));
            }
            match tokio::time::timeout(left, self.io.read(&mut buf)).await {
                Err(_) => {}
                Ok(Ok(0)) => return Err("the controller closed the line".into()),
                Ok(Ok(n)) => out.extend_from_slice(&buf[..n]),
                Ok(Err(e)) => return Err(format!("reading: {e}")),
            }
        }
        let mut out = String::from_utf8_lossy(&out).into_owned();
        out += &self.said(Duration::from_millis(80)).await?;
        Ok(out)
    }
    async fn ask(&mut self, bytes: &[u8]) -> Result<String, String> {
        self.send(bytes).await?;
        self.said(Duration::from_millis(80)).await
    }
    /// `ask`, for an answer that is due: its first bytes are waited for up to 3 s (a
    /// loaded machine may be slow to answer), the rest until 80 ms of quiet.
    async fn ask_due(&mut self, bytes: &[u8]) -> Result<String, String> {
        self.send(bytes).await?;
        let mut buf = [0u8; 1024];
        let first = match tokio::time::timeout(Duration::from_secs(3), self.io.read(&mut buf)).await
        {
            Err(_) => return Ok(String::new()),
            Ok(Ok(0)) => return Err("the controller closed the line".into()),
            Ok(Ok(n)) => String::from_utf8_lossy(&buf[..n]).into_owned(),
            Ok(Err(e)) => return Err(format!("reading: {e}")),
        };
        Ok(first + &self.said(Duration::from_millis(80)).await?)
    }
    /// The state word of a fresh status report (waited for up to 3 s: GRBL answers `?`
    /// whatever it is doing, and a loaded machine may be slow to).
    async fn state(&mut self) -> Result<String, String> {
        self.send(b"?").await?;
        let r = self.said_through(">", Duration::from_secs(3)).await?;
        let r = r.trim();
        if !(r.starts_with('<') && r.ends_with('>')) {
            return Err(format!("`?` got {r:?}, not one status report"));
        }
        Ok(r[1..]
            .split(['|', ':', '>'])
            .next()
            .unwrap_or("")
            .to_string())
    }
    async fn expect(&mut self, bytes: &[u8], want: &str) -> Result<(), String> {
        self.send(bytes).await?;
        let got = self
            .said_through(want, Duration::from_secs(3))
            .await
            .unwrap_or_else(|e| e);
        if got.contains(want) {
            Ok(())
        } else {
            Err(format!(
                "setting up: {:?} got {got:?}",
                String::from_utf8_lossy(bytes)
            ))
        }
    }
}

fn matches(answer: Answer, said: &str) -> bool {
    let lines: Vec<&str> = said.split("\r\n").collect();
    match answer {
        Answer::Ok => said == "ok\r\n",
        Answer::Error(n) => said == format!("error:{n}\r\n"),
        Answer::Report => said.starts_with('<') && said.ends_with(">\r\n") && lines.len() == 2,
        Answer::Banner => said == BANNER,
        Answer::BannerLocked => said == format!("{BANNER}{UNLOCK}"),
        Answer::ResetInMotion => said == format!("ALARM:3\r\n{BANNER}{UNLOCK}"),
        Answer::Unlocked => said == "[MSG:Caution: Unlocked]\r\nok\r\n",
        Answer::CheckOn => said == "[MSG:Enabled]\r\nok\r\n",
        Answer::CheckOff => said == format!("[MSG:Disabled]\r\nok\r\n{BANNER}"),
        Answer::SettingsList => {
            said.ends_with("ok\r\n")
                && lines.len() > 3
                && lines[..lines.len() - 2]
                    .iter()
                    .all(|l| l.starts_with('$') && l.contains('='))
        }
        Answer::Build => {
            lines.len() == 4
                && lines[0].starts_with("[VER:")
                && lines[1].starts_with("[OPT:")
                && lines[2] == "ok"
        }
        Answer::Silence => said.is_empty(),
    }
}

/// Takes a fresh controller (just powered up; for `AlarmBeforeReset`, one that raises an
/// alarm on its first G-code line, as a limit switch would) on `io` to `column`, sends
/// `ask`, and checks what it says and the state its next status report names.
pub async fn check<S>(io: S, column: Column, ask: Ask) -> Result<(), String>
where
    S: AsyncRead + AsyncWrite + Unpin,
{
    let want = cell(ask, column);
    let mut l = Line { io };
    // the power-up banner (and, for a controller that powers up locked, its unlock message)
    l.said_through("['$' for help]", Duration::from_secs(10))
        .await?;
    match column {
        Column::Idle => {}
        Column::Run | Column::Hold | Column::Alarm => {
            // a minute of motion at 100 mm/min
            l.expect(b"G1 X100 F100\n", "ok").await?;
            match column {
                Column::Hold => l.send(b"!").await?,
                Column::Alarm => l.expect(&[0x18], "ALARM:3").await?,
                _ => {}
            }
        }
        Column::AlarmBeforeReset => l.expect(b"G1 X1 F100\n", "ALARM:").await?,
        Column::Check => l.expect(b"$C\n", "[MSG:Enabled]").await?,
    }
    let before = l.state().await?;
    if before != column.word() {
        return Err(format!(
            "setting up reached {before}, not {}",
            column.word()
        ));
    }
    let said = if want.answer == Answer::Silence {
        l.ask(&ask.bytes()).await?
    } else {
        l.ask_due(&ask.bytes()).await?
    };
    if !matches(want.answer, &said) {
        return Err(format!(
            "it said {said:?}, where {} is due",
            answer_text(want.answer)
        ));
    }
    let next = want.next.unwrap_or(column);
    let after = l.state().await?;
    if after != next.word() {
        return Err(format!(
            "its status report names {after} afterwards, where {} is due",
            next.word()
        ));
    }
    // Only a reset lets a raised alarm take lines again: one sent before it is never run.
    if column == Column::AlarmBeforeReset && want.next.is_none() {
        let later = l.ask_due(&[0x18]).await?;
        if !matches(Answer::BannerLocked, &later) {
            return Err(format!("the reset after it said {later:?}"));
        }
    }
    Ok(())
}
