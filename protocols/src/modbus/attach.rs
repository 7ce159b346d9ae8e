//! The Modbus link after the daemon restarted or the device came back: where the device is
//! with a program, read from its header (state, write and consumed sequences) and checked
//! against the ring (the slot of the last block it holds must be this program's), and the
//! journal of the sync that hands it a program.

use super::link::{ModbusError, ModbusLink};
use super::map::{fault_name, ModbusState, MotionBlock};
use super::ring::Ring;
use crate::link::{Handed, Reattach};

impl Ring {
    /// Journals that a sync at `from` is about to hand the device blocks `from..total`, so
    /// that a restarted daemon knows this job reached the device.
    pub(crate) fn journal_sync(&mut self, from: u32, total: u32) -> Result<(), ModbusError> {
        if let Some(j) = self.journal.as_mut() {
            j.sending(from as usize, total as usize)
                .map_err(|e| ModbusError::Protocol {
                    target: self.target.clone(),
                    message: format!("cannot journal the job's start: {e}"),
                })?;
        }
        Ok(())
    }

    /// Journals that the sync went out: the device holds this job from now on.
    pub(crate) fn journal_synced(&mut self, total: u32) -> Result<(), ModbusError> {
        if let Some(j) = self.journal.as_mut() {
            j.sent(total as usize).map_err(|e| ModbusError::Protocol {
                target: self.target.clone(),
                message: format!("cannot journal the job's start: {e}"),
            })?;
        }
        Ok(())
    }
}

impl ModbusLink {
    /// Where `blocks` stand on the device: still running (followed from its consumed
    /// sequence, feeding the ring from its write sequence), stopped after its consumed
    /// sequence, or done. The device's own sequences are the truth once the ring shows it
    /// holds this program; a job whose sync never went out falls back on the journal.
    pub(super) async fn where_is(
        &mut self,
        blocks: &[MotionBlock],
        handed: Handed,
    ) -> Result<Reattach, ModbusError> {
        let total = blocks.len() as u32;
        let journal = Reattach::Stopped {
            next: handed.acked.min(blocks.len()),
        };
        if handed.sending == 0 || handed.sending > handed.sent {
            // this job never reached the device, or the daemon stopped between the journal
            // and the sync: nothing of it ran beyond the journal's point
            return Ok(journal);
        }
        let s = self.ring.read_status(&mut self.session).await?;
        let last = s.write_seq.max(s.consumed_seq);
        let ours = last <= total
            && s.consumed_seq <= s.write_seq.max(s.consumed_seq)
            && (last == 0
                || self
                    .ring
                    .slots_match(&mut self.session, blocks, last, last)
                    .await?[0]);
        if !ours {
            return Ok(Reattach::Unsure {
                next: handed.acked.min(blocks.len()),
                why: format!(
                    "the device's ring holds blocks of another program (write sequence {}, consumed {}), so it cannot say how far this one got; the journal's last block is used",
                    s.write_seq, s.consumed_seq
                ),
            });
        }
        let consumed = s.consumed_seq as usize;
        Ok(match ModbusState::from_register(s.state) {
            // a device that ran every block it was given stands still, waiting for more: it
            // is stopped until the operator's resume feeds it again (nothing moves before)
            Some(ModbusState::Running) if s.write_seq <= s.consumed_seq && s.consumed_seq < total => {
                Reattach::Stopped { next: consumed }
            }
            Some(ModbusState::Running | ModbusState::Hold) => Reattach::Running { acked: consumed },
            Some(ModbusState::Idle) if s.consumed_seq >= total => Reattach::Completed,
            Some(ModbusState::Idle) => Reattach::Stopped { next: consumed },
            Some(ModbusState::Fault) => Reattach::Unsure {
                next: consumed,
                why: format!(
                    "the device is in fault 0x{:04X} ({}) at block {}: clear it at the machine, then resume",
                    s.fault,
                    fault_name(s.fault),
                    consumed + 1
                ),
            },
            None => Reattach::Unsure {
                next: handed.acked.min(blocks.len()),
                why: format!("the device reports state {}, which the map does not know", s.state),
            },
        })
    }
}
