//! The GRBL link between and after jobs: following a controller that still runs lines an
//! earlier connection handed it, the operator's commands (`$X`, `$H`, `$J=`) and overrides.

use super::reply::{classify, Reply};
use super::resume::end_positions;
use super::{realtime, take, GrblLink, MIN_STATUS_INTERVAL};
use crate::link::{
    Control, DeviceState, Handed, LinkError, LinkEvent, Operation, OperatorReason, Overrides,
    Reattach,
};
use crate::program::Units;
use std::time::Duration;
use tokio::sync::{mpsc, watch};
use tokio::time::Instant;

/// How close (mm) the tool must be to where a line ends to count as having run it.
const AT_LINE_END: f64 = 0.01;

impl GrblLink {
    /// Follows what the controller still holds of `lines` after a restart of the daemon or a
    /// reconnect, until it stands idle; then says where the program stands. Lines handed to
    /// a controller that did not restart all run (GRBL runs what it received), so the next
    /// line is the first the journal says was never handed over. Nothing is sent but status
    /// requests and what the operator asks for (hold, cycle start, cancel).
    pub(super) async fn follow(
        &mut self,
        lines: Units<'_, String>,
        handed: Handed,
        events: mpsc::UnboundedSender<LinkEvent>,
        mut control: watch::Receiver<Control>,
    ) -> Result<Reattach, LinkError> {
        let n = lines.len();
        let acked = handed.acked.min(n);
        let held_lines = handed.sending.max(handed.sent).min(n).saturating_sub(acked);
        if self.restarted {
            if handed.sending == 0 && handed.sent == 0 && acked == 0 {
                return Ok(Reattach::Stopped { next: 0 });
            }
            return Ok(Reattach::Unsure {
                next: acked,
                why: format!(
                    "the controller restarted (it greeted with its banner when its port was opened), so the {} lines it had planned or received were lost unrun; check the part and resume from the first line not cut",
                    held_lines + self.planner_blocks.unwrap_or(15).min(acked)
                ),
            });
        }
        let mut poll = tokio::time::interval(self.opts.status_interval.max(MIN_STATUS_INTERVAL));
        poll.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        let mut last_heard = Instant::now();
        let mut idle_seen = 0u32;
        let mut held = false;
        let mut control_open = true;
        // asked to go on (the operator's resume): a controller found holding is let go,
        // once; after a stop (a restart, a link back) it stays held until the operator says
        let mut let_go = false;
        let initial = *control.borrow_and_update();
        match initial {
            Control::Hold => {
                self.write(&[realtime::FEED_HOLD]).await?;
                held = true;
            }
            Control::Run => let_go = handed.go_on,
            Control::Cancel => {}
        }
        loop {
            tokio::select! {
                _ = poll.tick() => self.write(&[realtime::STATUS]).await?,
                item = self.lines.recv() => {
                    let line = take(item)?;
                    last_heard = Instant::now();
                    match classify(&line) {
                        Reply::Status(s) => {
                            if s.wco.is_some() {
                                self.wco = s.wco;
                            }
                            let mut status = s.to_status(self.wco);
                            if std::mem::take(&mut let_go) && matches!(s.state.as_str(), "Hold" | "Door") {
                                self.write(&[realtime::CYCLE_START]).await?;
                                idle_seen = 0;
                                let _ = events.send(LinkEvent::Message(
                                    "the machine held the lines it was running: cycle start lets it finish them".into(),
                                ));
                                continue;
                            }
                            match s.state.as_str() {
                                "Idle" => {
                                    let planner_empty = match (s.buffer, self.planner_blocks) {
                                        (Some((free, _)), Some(total)) => free as usize >= total,
                                        _ => false,
                                    };
                                    idle_seen += 1;
                                    if planner_empty || idle_seen >= 2 {
                                        let _ = events.send(LinkEvent::Status(status));
                                        break;
                                    }
                                }
                                "Alarm" => {
                                    let _ = events.send(LinkEvent::Status(status));
                                    return Ok(Reattach::Unsure {
                                        next: acked,
                                        why: "the controller is in alarm: it stopped and dropped the lines it held; clear the alarm, check the part and resume from the first line not cut".into(),
                                    });
                                }
                                "Hold" | "Door" if !held => {
                                    idle_seen = 0;
                                    status.state = DeviceState::NeedsOperator {
                                        reason: OperatorReason::Other {
                                            text: "the machine holds the lines it was running; resume lets it finish them".into(),
                                        },
                                    };
                                }
                                _ => idle_seen = 0,
                            }
                            let _ = events.send(LinkEvent::Status(status));
                        }
                        Reply::Alarm(code) => {
                            return Ok(Reattach::Unsure {
                                next: acked,
                                why: format!(
                                    "the controller raised {} while finishing the lines it held; check the part and resume from the first line not cut",
                                    super::codes::describe_alarm(code)
                                ),
                            });
                        }
                        Reply::Banner(b) => {
                            self.banner = b;
                            return Ok(Reattach::Unsure {
                                next: acked,
                                why: "the controller restarted while finishing the lines it held; check the part and resume from the first line not cut".into(),
                            });
                        }
                        Reply::Error(code) => {
                            let _ = events.send(LinkEvent::Message(format!(
                                "the controller refused one of the lines it held: {}",
                                super::codes::describe_error(code)
                            )));
                        }
                        Reply::Bracket(m) if m.starts_with("[MSG:") => {
                            let _ = events.send(LinkEvent::Message(m));
                        }
                        // the answers to lines the earlier connection sent
                        _ => {}
                    }
                }
                changed = control.changed(), if control_open => {
                    if changed.is_err() {
                        control_open = false;
                        continue;
                    }
                    let c = *control.borrow_and_update();
                    match c {
                        Control::Hold => {
                            self.write(&[realtime::FEED_HOLD]).await?;
                            held = true;
                        }
                        Control::Run => {
                            self.write(&[realtime::CYCLE_START]).await?;
                            held = false;
                        }
                        Control::Cancel => {
                            self.recover(true).await?;
                            self.journal_reset(acked);
                            return Ok(Reattach::Unsure {
                                next: acked,
                                why: "cancelled while the machine finished the lines it held; the reset dropped those it had not run".into(),
                            });
                        }
                    }
                }
                _ = tokio::time::sleep_until(last_heard + self.opts.ack_timeout) => {
                    return Err(LinkError::Timeout(self.opts.ack_timeout));
                }
            }
        }
        let next = self.settle_doubt(lines, handed, &events).await?;
        if next < n {
            // an idle controller may hold half a line cut off in the wire: a reset (harmless
            // while nothing moves; a resume restores the modes) clears it
            self.recover(false).await?;
        }
        self.read_info().await?;
        Ok(if next >= n {
            Reattach::Completed
        } else {
            Reattach::Stopped { next }
        })
    }

    /// The first line the idle controller has not run. Lines `sent..sending` were being
    /// written when the daemon stopped: where the tool stands tells whether they arrived
    /// (they are taken as not arrived, and sent again, when they do not move the tool:
    /// repeating a line that does not move is harmless, skipping one that starts the
    /// spindle is not).
    async fn settle_doubt(
        &mut self,
        lines: Units<'_, String>,
        handed: Handed,
        events: &mpsc::UnboundedSender<LinkEvent>,
    ) -> Result<usize, LinkError> {
        let n = lines.len();
        let sent = handed.sent.max(handed.acked).min(n);
        let sending = handed.sending.max(sent).min(n);
        if handed.cut_off {
            return self.settle_cut_off(lines, handed, events).await;
        }
        if sending == sent {
            return Ok(sent);
        }
        // the positions at the ends of lines sent - 1 ..= sending - 1
        let base = sent.saturating_sub(1);
        let ends = end_positions(lines, base..sending)?;
        let before = if sent == 0 {
            [None; 3]
        } else {
            ends[sent - 1 - base]
        };
        let after = ends[sending - 1 - base];
        let same = (0..3).all(|k| match (before[k], after[k]) {
            (Some(a), Some(b)) => (a - b).abs() < AT_LINE_END,
            (None, None) => true,
            _ => false,
        });
        if same {
            return Ok(sent);
        }
        let pos = self.work_position().await?;
        let at = |p: [Option<f64>; 3]| {
            (0..3).all(|k| p[k].is_none_or(|v| (v - pos[k]).abs() < AT_LINE_END))
        };
        if at(after) {
            Ok(sending)
        } else {
            if !at(before) {
                let _ = events.send(LinkEvent::Message(format!(
                    "the machine stands at X{:.3} Y{:.3} Z{:.3}, at the end of neither line {sent} nor line {sending}; taking line {} as the next",
                    pos[0], pos[1], pos[2], sent + 1
                )));
            }
            Ok(sent)
        }
    }

    /// After the link dropped: the lines after the last acknowledged one may have been lost
    /// on the way (the controller runs a prefix of them, in order), so where the tool stands
    /// says how many ran: the last line ending there. Lines that do not move, at the end of
    /// that prefix, are taken as lost (sent again) rather than skipped.
    async fn settle_cut_off(
        &mut self,
        lines: Units<'_, String>,
        handed: Handed,
        events: &mpsc::UnboundedSender<LinkEvent>,
    ) -> Result<usize, LinkError> {
        let n = lines.len();
        let lo = handed.acked.min(n);
        let hi = handed.sending.max(handed.sent).max(lo).min(n);
        if hi == lo {
            return Ok(lo);
        }
        // the positions at the ends of lines lo - 2 ..= hi - 1, as far as they exist
        let base = lo.saturating_sub(2);
        let ends = end_positions(lines, base..hi)?;
        let end = |k: usize| ends[k - base];
        let pos = self.work_position().await?;
        let near = |p: [Option<f64>; 3], q: [Option<f64>; 3]| {
            (0..3).all(|k| match (p[k], q[k]) {
                (Some(a), Some(b)) => (a - b).abs() < AT_LINE_END,
                (None, None) => true,
                _ => false,
            })
        };
        let here = pos.map(Some);
        let at = |k: usize| k > 0 && near(end(k - 1), here);
        let Some(mut k) = (lo..=hi).rev().find(|&k| at(k)) else {
            let _ = events.send(LinkEvent::Message(format!(
                "the machine stands at X{:.3} Y{:.3} Z{:.3}, at the end of none of lines {}..{}; taking line {} as the next",
                pos[0], pos[1], pos[2], lo + 1, hi, lo + 1
            )));
            return Ok(lo);
        };
        while k > lo && k >= 2 && near(end(k - 1), end(k - 2)) {
            k -= 1;
        }
        Ok(k)
    }

    /// The tool's work position, waiting (a few reports) for the work offset to be known.
    async fn work_position(&mut self) -> Result<[f64; 3], LinkError> {
        let mut last = None;
        for _ in 0..40 {
            let s = self.query_status().await?;
            if s.wpos.is_some() || s.wco.is_some() || self.wco.is_some() {
                return Ok(s.to_status(self.wco).position);
            }
            last = Some(s);
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        Ok(last.map(|s| s.to_status(None).position).unwrap_or([0.0; 3]))
    }

    /// Carries out an operator's operation between jobs.
    pub(super) async fn operator(&mut self, op: &Operation) -> Result<String, LinkError> {
        op.check().map_err(|e| LinkError::Rejected {
            unit: 0,
            text: op.name(),
            reason: e,
        })?;
        match op {
            Operation::Unlock => {
                let said = self.send_setting("$X").await?;
                Ok(if said.is_empty() {
                    "unlocked ($X)".into()
                } else {
                    format!("unlocked ($X): {}", said.replace('\n', " "))
                })
            }
            Operation::Home => {
                // a homing cycle answers when it is over, which takes a while on a big machine
                let wait = self.opts.ack_timeout;
                self.opts.ack_timeout = wait.max(Duration::from_secs(120));
                let r = self.send_setting("$H").await;
                self.opts.ack_timeout = wait;
                r?;
                let s = self.query_status().await?.to_status(self.wco);
                Ok(format!(
                    "homed ($H): the machine stands at X{:.3} Y{:.3} Z{:.3}",
                    s.position[0], s.position[1], s.position[2]
                ))
            }
            Operation::Jog { x, y, z, feed } => {
                let mut line = "$J=G91 G21".to_string();
                for (axis, v) in [('X', x), ('Y', y), ('Z', z)] {
                    if let Some(v) = v {
                        line.push_str(&format!(" {axis}{}", crate::gcode::num(*v)));
                    }
                }
                line.push_str(&format!(" F{}", crate::gcode::num(*feed)));
                self.send_setting(&line).await?;
                let dist = [x, y, z]
                    .iter()
                    .filter_map(|v| **v)
                    .map(|v| v * v)
                    .sum::<f64>()
                    .sqrt();
                let give_up = Instant::now()
                    + Duration::from_secs_f64((dist / feed * 60.0 * 2.0).min(3600.0))
                    + Duration::from_secs(30);
                loop {
                    let s = self.query_status().await?;
                    if s.state == "Idle" {
                        let p = s.to_status(self.wco).position;
                        return Ok(format!(
                            "jogged ({}): the machine stands at X{:.3} Y{:.3} Z{:.3}",
                            line, p[0], p[1], p[2]
                        ));
                    }
                    if s.state == "Alarm" {
                        return Err(LinkError::Alarm {
                            code: None,
                            text: format!("the machine went into alarm while jogging ({line})"),
                        });
                    }
                    if Instant::now() > give_up {
                        self.write(&[realtime::JOG_CANCEL]).await?;
                        return Err(LinkError::Timeout(Duration::from_secs(30)));
                    }
                    tokio::time::sleep(MIN_STATUS_INTERVAL).await;
                }
            }
        }
    }

    /// Sets the controller's overrides to `want` with GRBL's real-time bytes: back to
    /// 100 % first, then steps of 10 % and 1 %.
    pub(super) async fn set_overrides(&mut self, want: Overrides) -> Result<(), LinkError> {
        want.check().map_err(LinkError::Protocol)?;
        let have = self.device_overrides;
        let mut bytes = Vec::new();
        if want.feed != have.feed {
            bytes.push(realtime::FEED_OV_RESET);
            steps(
                want.feed,
                [
                    realtime::FEED_OV_PLUS_10,
                    realtime::FEED_OV_MINUS_10,
                    realtime::FEED_OV_PLUS_1,
                    realtime::FEED_OV_MINUS_1,
                ],
                &mut bytes,
            );
        }
        if want.spindle != have.spindle {
            bytes.push(realtime::SPINDLE_OV_RESET);
            steps(
                want.spindle,
                [
                    realtime::SPINDLE_OV_PLUS_10,
                    realtime::SPINDLE_OV_MINUS_10,
                    realtime::SPINDLE_OV_PLUS_1,
                    realtime::SPINDLE_OV_MINUS_1,
                ],
                &mut bytes,
            );
        }
        if want.rapid != have.rapid {
            bytes.push(match want.rapid {
                25 => realtime::RAPID_OV_LOW,
                50 => realtime::RAPID_OV_MEDIUM,
                _ => realtime::RAPID_OV_RESET,
            });
        }
        if !bytes.is_empty() {
            self.write(&bytes).await?;
        }
        self.device_overrides = want;
        Ok(())
    }
}

/// The override bytes that take 100 % to `target` %: [+10, -10, +1, -1].
fn steps(target: u16, codes: [u8; 4], out: &mut Vec<u8>) {
    let diff = target as i32 - 100;
    let tens = diff / 10;
    let ones = diff % 10;
    let (t, o) = (tens.unsigned_abs() as usize, ones.unsigned_abs() as usize);
    out.extend(std::iter::repeat_n(
        if tens >= 0 { codes[0] } else { codes[1] },
        t,
    ));
    out.extend(std::iter::repeat_n(
        if ones >= 0 { codes[2] } else { codes[3] },
        o,
    ));
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn override_steps_reach_the_target_from_100() {
        let mut b = Vec::new();
        steps(135, [1, 2, 3, 4], &mut b);
        assert_eq!(b, [1, 1, 1, 3, 3, 3, 3, 3]);
        b.clear();
        steps(72, [1, 2, 3, 4], &mut b);
        assert_eq!(b, [2, 2, 4, 4, 4, 4, 4, 4, 4, 4]);
        b.clear();
        steps(100, [1, 2, 3, 4], &mut b);
        assert!(b.is_empty());
    }
}
