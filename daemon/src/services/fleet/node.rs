//! The daemon's side of the fleet: takes its machines' jobs off the group's queue into its
//! store (acknowledging each only once stored), and keeps the fleet's view of its machines
//! and jobs current from its scheduler's events.

use super::{
    bucket, connect, consumer_name, job_key, job_stream, job_subject, machine_key, FleetConfig,
    FleetError, FleetJob, FleetMachine, Submission,
};
use crate::core::intake::{self, Target};
use crate::core::scheduler::{Event, Scheduler};
use crate::core::store::{now_ms, JobId, JobRecord, NewJob};
use crate::services::metrics::Metrics;
use async_nats::jetstream::{self, consumer::pull, AckKind};
use futures::StreamExt;
use std::collections::HashMap;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::broadcast;
use tokio::task::JoinSet;

/// The fleet id a stored job carries in its parameters, if it came from the fleet.
pub fn fleet_id(j: &JobRecord) -> Option<&str> {
    j.params.get("fleet_id").and_then(|v| v.as_str())
}

/// The fleet's view of a stored job.
fn fleet_job(daemon: &str, j: &JobRecord, id: &str) -> FleetJob {
    FleetJob {
        id: id.to_string(),
        machine: j.machine.clone(),
        state: j.state.as_str().to_string(),
        daemon: Some(daemon.to_string()),
        local_id: Some(j.id),
        acked: j.acked_units,
        total: j.total_units,
        error: j.error.clone(),
        file_name: j.file_name.clone(),
        updated_ms: now_ms(),
    }
}

struct Node {
    cfg: FleetConfig,
    sched: Scheduler,
    metrics: Arc<Metrics>,
    kv: jetstream::kv::Store,
}

/// Runs the daemon's part in the fleet until the daemon stops: connects (retrying while
/// NATS is away), announces its machines, writes every fleet job of its store to the view
/// (the store is the authority), then takes jobs and follows events.
pub async fn run(cfg: FleetConfig, sched: Scheduler, metrics: Arc<Metrics>) {
    // subscribe first: no state change between the reconciliation and the follower is lost
    let events = sched.subscribe();
    let mut backoff = Duration::from_millis(200);
    let (node, stream) = loop {
        match setup(&cfg, &sched, &metrics).await {
            Ok(x) => break x,
            Err(e) => {
                tracing::warn!(fleet = %cfg.url, "{e}; trying again in {backoff:?}");
                tokio::time::sleep(backoff).await;
                backoff = (backoff * 2).min(Duration::from_secs(10));
            }
        }
    };
    let node = Arc::new(node);
    let mut tasks = JoinSet::new();
    tasks.spawn(node.clone().follow(events));
    let names: Vec<String> = sched
        .machines()
        .unwrap_or_default()
        .into_iter()
        .map(|m| m.name)
        .collect();
    for m in cfg.owned(&names) {
        tasks.spawn(node.clone().take_jobs(stream.clone(), m));
    }
    tracing::info!(fleet = %cfg.url, daemon = %cfg.name, group = %cfg.group, "joined the fleet");
    // the tasks run until the daemon stops (dropping this future aborts them)
    while tasks.join_next().await.is_some() {}
}

async fn setup(
    cfg: &FleetConfig,
    sched: &Scheduler,
    metrics: &Arc<Metrics>,
) -> Result<(Node, jetstream::stream::Stream), FleetError> {
    sched.store().index_fleet_ids()?;
    let client = connect(&cfg.url, cfg.credentials.as_deref(), &cfg.name).await?;
    let js = jetstream::new(client);
    let kv = bucket(&js).await?;
    let stream = job_stream(&js, &cfg.group).await?;
    let node = Node {
        cfg: cfg.clone(),
        sched: sched.clone(),
        metrics: metrics.clone(),
        kv,
    };
    node.reconcile().await?;
    Ok((node, stream))
}

impl Node {
    async fn put<T: serde::Serialize>(&self, key: &str, v: &T) -> Result<(), FleetError> {
        let bytes = serde_json::to_vec(v).map_err(|e| FleetError::js(key, e))?;
        self.kv
            .put(key, bytes.into())
            .await
            .map(|_| ())
            .map_err(|e| FleetError::js(format!("writing {key}"), e))
    }

    /// Announces the machines this daemon owns and writes every fleet job of its store.
    async fn reconcile(&self) -> Result<(), FleetError> {
        let names: Vec<String> = self
            .sched
            .machines()
            .unwrap_or_default()
            .into_iter()
            .map(|m| m.name)
            .collect();
        let owned = self.cfg.owned(&names);
        for m in self.sched.machines().unwrap_or_default() {
            if owned.contains(&m.name) {
                self.put_machine(&m).await?;
            }
        }
        let jobs = self.sched.jobs()?;
        for j in &jobs {
            if let Some(id) = fleet_id(j) {
                self.put(&job_key(id), &fleet_job(&self.cfg.name, j, id))
                    .await?;
            }
        }
        Ok(())
    }

    async fn put_machine(&self, m: &crate::core::scheduler::MachineInfo) -> Result<(), FleetError> {
        self.put(
            &machine_key(&m.name),
            &FleetMachine {
                name: m.name.clone(),
                daemon: self.cfg.name.clone(),
                group: self.cfg.group.clone(),
                link: m.link.clone(),
                status: m.status.clone(),
                job: m.job,
                updated_ms: now_ms(),
            },
        )
        .await
    }

    /// Takes `machine`'s jobs off the queue, one at a time, for as long as the daemon runs.
    async fn take_jobs(self: Arc<Self>, stream: jetstream::stream::Stream, machine: String) {
        let name = consumer_name(&machine);
        let config = pull::Config {
            durable_name: Some(name.clone()),
            filter_subject: job_subject(&self.cfg.group, &machine),
            ack_policy: jetstream::consumer::AckPolicy::Explicit,
            ack_wait: self.cfg.ack_wait(),
            max_ack_pending: 64,
            ..Default::default()
        };
        let mut backoff = Duration::from_millis(200);
        loop {
            let r = async {
                let consumer = stream
                    .get_or_create_consumer(&name, config.clone())
                    .await
                    .map_err(|e| FleetError::js(format!("the consumer {name}"), e))?;
                let mut messages = consumer
                    .messages()
                    .await
                    .map_err(|e| FleetError::js(format!("the consumer {name}"), e))?;
                while let Some(m) = messages.next().await {
                    match m {
                        Ok(m) => self.take(&machine, m).await,
                        Err(e) => tracing::warn!(%machine, "the fleet's queue: {e}"),
                    }
                }
                Ok::<(), FleetError>(())
            }
            .await;
            if let Err(e) = r {
                tracing::warn!(%machine, "{e}; trying again in {backoff:?}");
            }
            tokio::time::sleep(backoff).await;
            backoff = (backoff * 2).min(Duration::from_secs(10));
        }
    }

    /// One job from the queue: stored (or found stored already), then acknowledged.
    async fn take(&self, machine: &str, msg: jetstream::Message) {
        let sub: Submission = match serde_json::from_slice(&msg.payload) {
            Ok(s) => s,
            Err(e) => {
                tracing::warn!(%machine, "a message on the fleet's queue is not a job, dropped: {e}");
                let _ = msg.ack_with(AckKind::Term).await;
                return;
            }
        };
        match self.sched.store().job_by_fleet_id(&sub.id) {
            Ok(Some(j)) => {
                // stored before the daemon died, not acknowledged: never taken twice
                tracing::info!(job = j.id, %machine, fleet_id = %sub.id, "fleet job already stored; acknowledging it again");
                ack(&msg, &sub.id).await;
                return;
            }
            Ok(None) => {}
            Err(e) => {
                tracing::error!(%machine, fleet_id = %sub.id, "cannot look the job up in the store: {e}");
                let _ = msg
                    .ack_with(AckKind::Nak(Some(Duration::from_secs(1))))
                    .await;
                return;
            }
        }
        let Ok(config) = self.sched.machine_config(machine).cloned() else {
            let _ = msg
                .ack_with(AckKind::Nak(Some(Duration::from_secs(5))))
                .await;
            return;
        };
        let mut spec = sub.spec.clone();
        spec.machine = Some(machine.to_string());
        let started = Instant::now();
        let planned = {
            let spec = spec.clone();
            tokio::task::spawn_blocking(move || intake::plan(&spec, Target::Machine(&config))).await
        };
        let planned = match planned {
            Ok(Ok(p)) => p,
            Ok(Err(e)) => {
                tracing::warn!(%machine, fleet_id = %sub.id, "fleet job refused: {e}");
                let refused = FleetJob {
                    id: sub.id.clone(),
                    machine: machine.to_string(),
                    state: "refused".into(),
                    daemon: Some(self.cfg.name.clone()),
                    local_id: None,
                    acked: 0,
                    total: 0,
                    error: Some(e.to_string()),
                    file_name: spec.input.file_name.clone(),
                    updated_ms: now_ms(),
                };
                if let Err(e) = self.put(&job_key(&sub.id), &refused).await {
                    tracing::warn!("{e}");
                }
                ack(&msg, &sub.id).await;
                return;
            }
            Err(e) => {
                tracing::error!(%machine, fleet_id = %sub.id, "planning crashed: {e}");
                let _ = msg.ack_with(AckKind::Term).await;
                return;
            }
        };
        let mut params = crate::core::intake::params_of(&spec);
        if let Some(o) = params.as_object_mut() {
            o.insert("fleet_id".into(), sub.id.clone().into());
        }
        let planning = started.elapsed();
        match self.sched.submit(NewJob {
            machine: machine.to_string(),
            op: planned.operation,
            file_name: spec.input.file_name.clone(),
            params,
            program: planned.program,
        }) {
            Ok(rec) => {
                self.metrics.job_submitted(machine, planning);
                tracing::info!(job = rec.id, %machine, fleet_id = %sub.id, "took a job from the fleet");
                ack(&msg, &sub.id).await;
            }
            Err(e) => {
                tracing::error!(%machine, fleet_id = %sub.id, "cannot store a fleet job: {e}");
                let _ = msg
                    .ack_with(AckKind::Nak(Some(Duration::from_secs(1))))
                    .await;
            }
        }
    }

    /// Writes job states and machine status to the fleet's view as they change. One task,
    /// so the writes keep the order of the events.
    async fn follow(self: Arc<Self>, mut rx: broadcast::Receiver<Event>) {
        let names: Vec<String> = self
            .sched
            .machines()
            .unwrap_or_default()
            .into_iter()
            .map(|m| m.name)
            .collect();
        let owned = self.cfg.owned(&names);
        let mut ids: HashMap<JobId, Option<String>> = HashMap::new();
        // per machine: its last status, its job, and what the view shows of them
        let mut machines: HashMap<String, Shown> = HashMap::new();
        let mut dirty = false;
        let mut tick = tokio::time::interval(Duration::from_secs(2));
        loop {
            let ev = tokio::select! {
                r = rx.recv() => r,
                _ = tick.tick() => {
                    if dirty {
                        dirty = self.reconcile().await.is_err();
                    }
                    continue;
                }
            };
            let r = match ev {
                Ok(Event::State {
                    job,
                    machine,
                    state,
                    ..
                }) => {
                    let id = match ids.get(&job) {
                        Some(id) => id.clone(),
                        None => {
                            let id = self
                                .sched
                                .job(job)
                                .ok()
                                .and_then(|j| fleet_id(&j).map(String::from));
                            ids.insert(job, id.clone());
                            id
                        }
                    };
                    let mut r = Ok(());
                    if let (Some(id), Ok(j)) = (id, self.sched.job(job)) {
                        r = self
                            .put(&job_key(&id), &fleet_job(&self.cfg.name, &j, &id))
                            .await;
                    }
                    if state.is_final() {
                        ids.remove(&job);
                    }
                    if r.is_ok() && owned.contains(&machine) {
                        let m = machines.entry(machine.clone()).or_default();
                        m.job = (!state.is_final()).then_some(job);
                        r = self.show(&machine, m).await;
                    }
                    r
                }
                Ok(Event::Status {
                    machine, status, ..
                }) if owned.contains(&machine) => {
                    let m = machines.entry(machine.clone()).or_default();
                    m.status = status;
                    self.show(&machine, m).await
                }
                Ok(_) => Ok(()),
                Err(broadcast::error::RecvError::Lagged(_)) => self.reconcile().await,
                Err(broadcast::error::RecvError::Closed) => return,
            };
            if let Err(e) = r {
                tracing::warn!("the fleet's view is behind: {e}");
                dirty = true;
            }
        }
    }

    /// Writes a machine's entry when its state or job changed since last written.
    async fn show(&self, machine: &str, m: &mut Shown) -> Result<(), FleetError> {
        let now = (m.status.state.to_string(), m.job);
        if m.written.as_ref() == Some(&now) {
            return Ok(());
        }
        let link = self
            .sched
            .machine_config(machine)
            .map(|c| c.link.clone())
            .unwrap_or_default();
        self.put(
            &machine_key(machine),
            &FleetMachine {
                name: machine.to_string(),
                daemon: self.cfg.name.clone(),
                group: self.cfg.group.clone(),
                link,
                status: m.status.clone(),
                job: m.job,
                updated_ms: now_ms(),
            },
        )
        .await?;
        m.written = Some(now);
        Ok(())
    }
}

/// A machine as the follower last heard of it and last wrote it.
#[derive(Default)]
struct Shown {
    status: machlink_protocols::MachineStatus,
    job: Option<JobId>,
    written: Option<(String, Option<JobId>)>,
}

/// Acknowledges a job and waits for the server to confirm (a lost acknowledgement only
/// means a redelivery, which finds the job stored).
async fn ack(msg: &jetstream::Message, id: &str) {
    if let Err(e) = msg.double_ack().await {
        tracing::warn!(fleet_id = %id, "the fleet did not confirm an acknowledgement (the job will come again and be found stored): {e}");
    }
}
