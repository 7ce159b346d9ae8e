//! What a GRBL controller says: acknowledgements, errors, alarms, status reports and pushes.

use crate::link::{DeviceState, MachineStatus, OperatorReason};

/// One line from the controller, classified.
#[derive(Clone, Debug, PartialEq)]
pub enum Reply {
    /// `ok`: the oldest outstanding line was accepted.
    Ok,
    /// `error:N`: the oldest outstanding line was rejected.
    Error(u16),
    /// `ALARM:N`: the machine stopped; a push message, never an acknowledgement.
    Alarm(u16),
    /// `<…>`: a real-time status report.
    Status(StatusReport),
    /// The start-up banner (`Grbl 1.1h ['$' for help]`): the controller has just reset.
    Banner(String),
    /// `[MSG:…]`, `[GC:…]`, `[VER:…]`, `[OPT:…]` and other bracketed pushes.
    Bracket(String),
    /// Anything else (`$n=v` lines of `$$`, startup-line echoes).
    Other(String),
}

/// A parsed status report.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StatusReport {
    /// The state word without its sub-state (`Hold` of `Hold:0`).
    pub state: String,
    /// The sub-state (`0` of `Hold:0`), if any.
    pub substate: Option<u8>,
    pub mpos: Option<[f64; 3]>,
    pub wpos: Option<[f64; 3]>,
    pub wco: Option<[f64; 3]>,
    /// `Bf:` planner blocks free, RX bytes free.
    pub buffer: Option<(u32, u32)>,
    /// `Ln:` line number being executed.
    pub line_number: Option<u64>,
    /// `FS:` or `F:` feed (mm/min) and spindle speed.
    pub feed: Option<f64>,
    pub spindle: Option<f64>,
    /// `Ov:` feed, rapid and spindle overrides in percent.
    pub overrides: Option<[u32; 3]>,
}

impl StatusReport {
    /// The report as the link's `MachineStatus`: the work position when it can be
    /// known (WPos, or MPos minus the last work offset `wco`), else the machine position.
    pub fn to_status(&self, wco: Option<[f64; 3]>) -> MachineStatus {
        let position = match (self.wpos, self.mpos, self.wco.or(wco)) {
            (Some(w), _, _) => w,
            (None, Some(m), Some(o)) => [m[0] - o[0], m[1] - o[1], m[2] - o[2]],
            (None, Some(m), None) => m,
            (None, None, _) => [0.0; 3],
        };
        MachineStatus {
            state: self.device_state(),
            detail: match self.substate {
                Some(n) => format!("{}:{n}", self.state),
                None => self.state.clone(),
            },
            position,
            feed: self.feed.unwrap_or(0.0),
        }
    }

    /// GRBL's state word in the daemon's words. A `Hold` is taken as the operator's hold;
    /// the link, which knows whether it asked for one, turns the others into a program stop.
    pub fn device_state(&self) -> DeviceState {
        match self.state.as_str() {
            "Idle" | "Check" | "Sleep" => DeviceState::Idle,
            "Run" | "Jog" | "Home" => DeviceState::Running,
            "Hold" => DeviceState::Held,
            "Door" => DeviceState::NeedsOperator {
                reason: OperatorReason::Door,
            },
            "Alarm" => DeviceState::Alarm {
                code: None,
                text: "alarm lock: clear the cause, then unlock ($X) or home ($H)".into(),
            },
            _ => DeviceState::Unknown,
        }
    }
}

/// Classifies one line (without its line ending).
pub fn classify(line: &str) -> Reply {
    let line = line.trim();
    if line == "ok" {
        return Reply::Ok;
    }
    if let Some(n) = line.strip_prefix("error:") {
        if let Ok(code) = n.trim().parse() {
            return Reply::Error(code);
        }
    }
    if let Some(n) = line.strip_prefix("ALARM:") {
        if let Ok(code) = n.trim().parse() {
            return Reply::Alarm(code);
        }
    }
    if line.starts_with('<') && line.ends_with('>') {
        if let Some(s) = parse_status(line) {
            return Reply::Status(s);
        }
    }
    if line.starts_with("Grbl ") || line.starts_with("GrblHAL ") {
        return Reply::Banner(line.to_string());
    }
    if line.starts_with('[') && line.ends_with(']') {
        return Reply::Bracket(line.to_string());
    }
    Reply::Other(line.to_string())
}

fn parse_xyz(s: &str) -> Option<[f64; 3]> {
    let mut it = s.split(',').map(|v| v.trim().parse::<f64>());
    let x = it.next()?.ok()?;
    let y = it.next()?.ok()?;
    let z = it.next()?.ok()?;
    Some([x, y, z])
}

/// Parses `<Idle|MPos:0.000,0.000,0.000|Bf:15,128|FS:0,0|WCO:…|Ov:100,100,100>`;
/// None when the report is not well formed. Unknown fields are skipped.
pub fn parse_status(line: &str) -> Option<StatusReport> {
    let inner = line.trim().strip_prefix('<')?.strip_suffix('>')?;
    let mut fields = inner.split('|');
    let state_field = fields.next()?;
    let (state, substate) = match state_field.split_once(':') {
        Some((s, sub)) => (s.to_string(), sub.parse().ok()),
        None => (state_field.to_string(), None),
    };
    if state.is_empty() {
        return None;
    }
    let mut r = StatusReport {
        state,
        substate,
        ..Default::default()
    };
    for f in fields {
        let Some((key, val)) = f.split_once(':') else {
            continue;
        };
        match key {
            "MPos" => r.mpos = Some(parse_xyz(val)?),
            "WPos" => r.wpos = Some(parse_xyz(val)?),
            "WCO" => r.wco = Some(parse_xyz(val)?),
            "Bf" => {
                let (a, b) = val.split_once(',')?;
                r.buffer = Some((a.trim().parse().ok()?, b.trim().parse().ok()?));
            }
            "Ln" => r.line_number = val.trim().parse().ok(),
            "FS" => {
                let (f, s) = val.split_once(',')?;
                r.feed = Some(f.trim().parse().ok()?);
                r.spindle = Some(s.trim().parse().ok()?);
            }
            "F" => r.feed = Some(val.trim().parse().ok()?),
            "Ov" => {
                let v: Vec<u32> = val
                    .split(',')
                    .filter_map(|x| x.trim().parse().ok())
                    .collect();
                if v.len() == 3 {
                    r.overrides = Some([v[0], v[1], v[2]]);
                }
            }
            _ => {}
        }
    }
    Some(r)
}

/// Reads `[OPT:V,15,128]` into (planner blocks, RX buffer bytes).
pub fn parse_opt(line: &str) -> Option<(usize, usize)> {
    let inner = line.trim().strip_prefix("[OPT:")?.strip_suffix(']')?;
    let parts: Vec<&str> = inner.split(',').collect();
    if parts.len() < 3 {
        return None;
    }
    let blocks = parts[1].trim().parse().ok()?;
    let rx = parts[2].trim().parse().ok()?;
    Some((blocks, rx))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn status_reports_parse_with_every_field() {
        let r = parse_status(
            "<Hold:0|MPos:1.000,-2.500,3.000|Bf:15,128|FS:500,12000|WCO:1.000,1.000,0.000|Ln:7|Ov:100,50,120>",
        )
        .unwrap();
        assert_eq!(r.state, "Hold");
        assert_eq!(r.substate, Some(0));
        assert_eq!(r.buffer, Some((15, 128)));
        assert_eq!(r.line_number, Some(7));
        assert_eq!(r.overrides, Some([100, 50, 120]));
        let s = r.to_status(None);
        assert_eq!(s.position, [0.0, -3.5, 3.0]);
        assert_eq!(s.feed, 500.0);
        let idle = parse_status("<Idle|WPos:0.000,0.000,0.000|F:0>").unwrap();
        assert_eq!(idle.state, "Idle");
        assert_eq!(idle.wpos, Some([0.0; 3]));
        assert!(parse_status("<|MPos:1>").is_none());
        assert!(parse_status("<Idle|MPos:1,2>").is_none());
    }

    #[test]
    fn replies_are_classified_so_pushes_never_look_like_acks() {
        assert_eq!(classify("ok"), Reply::Ok);
        assert_eq!(classify("error:22"), Reply::Error(22));
        assert_eq!(classify("ALARM:1"), Reply::Alarm(1));
        assert!(matches!(
            classify("Grbl 1.1h ['$' for help]"),
            Reply::Banner(_)
        ));
        assert!(matches!(
            classify("[MSG:Caution: Unlocked]"),
            Reply::Bracket(_)
        ));
        assert!(matches!(classify("[GC:G0 G54 G17]"), Reply::Bracket(_)));
        assert!(matches!(classify("$110=500.000"), Reply::Other(_)));
        assert_eq!(parse_opt("[OPT:V,15,128]"), Some((15, 128)));
        assert_eq!(parse_opt("[OPT:VL,35,1024]"), Some((35, 1024)));
    }
}
