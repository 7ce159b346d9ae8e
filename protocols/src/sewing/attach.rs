//! The sewing link after the daemon restarted or the line came back: where the machine is
//! with a pattern, asked from its status (stitch counter, pattern length and CRC), and the
//! journal of the START that hands it a program.

use super::link::SewingLink;
use super::wire::SewingState;
use super::{pattern_crc, StitchRecord};
use crate::link::{Handed, LinkError, Reattach};

impl SewingState {
    /// Whether the machine is in the middle of a pattern: sewing, held, or waiting after a
    /// thread break.
    pub fn is_sewing(self) -> bool {
        matches!(
            self,
            SewingState::Sewing | SewingState::Held | SewingState::ThreadBreak
        )
    }
}

impl SewingLink {
    /// Journals that a START at `at` is about to hand the machine the pattern's records
    /// `at..len`, so that a restarted daemon knows this job's pattern was started.
    pub(super) fn journal_start(&mut self, at: usize, len: usize) -> Result<(), LinkError> {
        if let Some(j) = self.journal.as_mut() {
            j.sending(at, len).map_err(LinkError::Journal)?;
        }
        Ok(())
    }

    /// Journals that the START went out: the machine sews this job from now on.
    pub(super) fn journal_started(&mut self, len: usize) -> Result<(), LinkError> {
        if let Some(j) = self.journal.as_mut() {
            j.sent(len).map_err(LinkError::Journal)?;
        }
        Ok(())
    }

    /// Where `records` stand on the machine: still being sewn (followed from its counter),
    /// stopped at its counter, or done. The machine's counter, length and CRC survive a
    /// power loss, so they are the truth; a machine holding another pattern, or a job whose
    /// START never went out, falls back on the journal.
    pub(super) async fn where_is(
        &mut self,
        records: &[StitchRecord],
        handed: Handed,
    ) -> Result<Reattach, LinkError> {
        let len = records.len();
        let st = self.status().await?;
        let ours = st.pattern_len as usize == len && st.pattern_crc == pattern_crc(records);
        if handed.sending == 0 {
            // this job never started the machine: whatever it did was another job's
            return Ok(Reattach::Stopped {
                next: handed.acked.min(len),
            });
        }
        if !ours {
            return Ok(Reattach::Unsure {
                next: handed.acked.min(len),
                why: "the machine holds another pattern now, so it cannot say how far this one got; the journal's last stitch is used".into(),
            });
        }
        let counter = (st.counter as usize).min(len);
        if handed.sending > handed.sent && !st.state.is_sewing() {
            // the daemon stopped between the journal and the START, which did not go out
            return Ok(Reattach::Stopped {
                next: handed.acked.min(len),
            });
        }
        Ok(match st.state {
            s if s.is_sewing() => {
                self.follow = true;
                Reattach::Running { acked: counter }
            }
            SewingState::Done if counter >= len => Reattach::Completed,
            _ => Reattach::Stopped { next: counter },
        })
    }
}
