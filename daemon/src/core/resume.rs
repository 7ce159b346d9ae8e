//! What `machlink resume` will do, shown to the operator before anything moves: a held job
//! gets cycle start; a stopped one goes on at its exact next unit (or the line the operator
//! names), and the machine's kind says how it gets back there (GRBL: retract, restore the
//! modes, spin up, rapid over the start point, plunge). The command line asks for
//! confirmation (`--yes` for scripts) before it posts the resume.

use crate::core::machine::MachineConfig;
use crate::core::store::{JobId, JobRecord, JobState, Store, StoreError};
use serde::{Deserialize, Serialize};

/// Why a job cannot resume.
#[derive(Debug, thiserror::Error)]
pub enum ResumeError {
    /// Not from there, or not now: the sentence says why.
    #[error("{0}")]
    Conflict(String),
    #[error(transparent)]
    Store(#[from] StoreError),
}

/// A resume, described before it is made.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ResumePreview {
    pub job: JobId,
    pub state: JobState,
    /// The program line (1-based) the program goes on at.
    pub from_line: usize,
    pub total: usize,
    /// What the machine will do, in order, in the operator's words.
    pub steps: Vec<String>,
    /// Whether the machine moves before the program goes on (the operator confirms).
    pub moves: bool,
    /// What the daemon found on the machine, or why the job waits.
    pub note: Option<String>,
}

/// The resume of `job` on its machine `m` from `from_line` (1-based) or its resume point.
/// `active` is None when no worker holds the job, Some(None) when its stream is alive
/// (held), and Some(Some(unit)) when it waits for the operator after its machine came back.
pub fn preview(
    store: &Store,
    m: &MachineConfig,
    job: &JobRecord,
    from_line: Option<usize>,
    active: Option<Option<usize>>,
) -> Result<ResumePreview, ResumeError> {
    let conflict = |why: String| Err(ResumeError::Conflict(why));
    if let Some(l) = from_line {
        if l == 0 || l > job.total_units {
            return conflict(format!(
                "job {} has lines 1 to {}; it cannot resume from line {l}",
                job.id, job.total_units
            ));
        }
    }
    let from = match (job.state, active) {
        (JobState::Paused, Some(None)) => {
            if from_line.is_some() {
                return conflict(format!(
                    "job {} is held mid-stream; only a stopped job restarts from a line (cancel it first)",
                    job.id
                ));
            }
            return Ok(ResumePreview {
                job: job.id,
                state: job.state,
                from_line: job.acked_units + 1,
                total: job.total_units,
                steps: vec![
                    "cycle start: the machine goes on where it holds, with the lines it already has"
                        .into(),
                ],
                moves: false,
                note: job.note.clone(),
            });
        }
        (JobState::Paused, Some(Some(next))) => from_line.map_or(next, |l| l - 1),
        (JobState::Interrupted | JobState::Failed | JobState::Cancelled, None) => {
            from_line.map_or(job.acked_units, |l| l - 1)
        }
        (JobState::Interrupted, Some(_)) => {
            return conflict(format!(
                "job {} is being followed while the machine finishes what it holds; look again when it stands still",
                job.id
            ))
        }
        (s, _) => return conflict(format!("job {} is {s}; there is nothing to resume", job.id)),
    };
    let program = store
        .program(job.id)
        .and_then(|p| p.decode(m.kind.as_ref()))?;
    let plan = m
        .kind
        .resume_plan(&m.settings, &program, from)
        .map_err(|e| ResumeError::Conflict(format!("job {} cannot resume there: {e}", job.id)))?;
    let mut steps = plan.steps;
    if from_line.is_none() && job.started_ms.is_some() {
        steps.insert(
            0,
            "ask the machine where the job stands first (it goes on where the machine says, if that differs)".into(),
        );
    }
    Ok(ResumePreview {
        job: job.id,
        state: job.state,
        from_line: from + 1,
        total: job.total_units,
        steps,
        moves: plan.moves,
        note: job.note.clone(),
    })
}
