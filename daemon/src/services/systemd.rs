//! systemd integration: `Type=notify` readiness, and the watchdog kept alive while the
//! daemon answers (docs/install.md, contrib/machlink.service). Outside systemd (no
//! `NOTIFY_SOCKET`) every call here does nothing.

use crate::core::scheduler::Scheduler;
use sd_notify::NotifyState;
use std::time::Duration;

/// Tells systemd the daemon is ready (its socket is listening), with a status line.
pub fn ready(status: &str) {
    if let Err(e) = sd_notify::notify(&[NotifyState::Ready, NotifyState::Status(status)]) {
        tracing::warn!("cannot tell systemd the daemon is ready: {e}");
    }
}

/// Tells systemd the daemon is stopping.
pub fn stopping() {
    let _ = sd_notify::notify(&[NotifyState::Stopping]);
}

/// When systemd asks for a watchdog (`WatchdogSec=`), pings it at half the interval for as
/// long as the daemon's store answers: a daemon stuck on its store stops pinging and
/// systemd restarts it. Returns at once when no watchdog is asked for.
pub async fn watchdog(sched: Scheduler) {
    let Some(interval) = sd_notify::watchdog_enabled() else {
        return;
    };
    let period = (interval / 2).max(Duration::from_millis(100));
    let mut tick = tokio::time::interval(period);
    loop {
        tick.tick().await;
        let store = sched.store().clone();
        let healthy = tokio::time::timeout(
            period,
            tokio::task::spawn_blocking(move || store.count_by_machine_state().is_ok()),
        )
        .await;
        if matches!(healthy, Ok(Ok(true))) {
            let _ = sd_notify::notify(&[NotifyState::Watchdog]);
        } else {
            tracing::error!("the job store does not answer; not pinging systemd's watchdog");
        }
    }
}
