//! What every handler of the API shares.

use crate::core::planner::PlanFn;
use crate::core::scheduler::Scheduler;
use crate::services::access::Access;
use std::sync::Arc;

/// What every handler shares.
#[derive(Clone)]
pub struct AppState {
    pub sched: Scheduler,
    pub access: Arc<Access>,
    /// How a job is planned (in a forked child, see `planner`).
    pub planner: PlanFn,
    /// Jobs planned at once (`limits::MAX_CONCURRENT_PLANS`).
    pub plans: Arc<tokio::sync::Semaphore>,
}
