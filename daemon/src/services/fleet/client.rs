//! The fleet from any host: submit a job for a machine, list the fleet's jobs and machines.

use super::{
    bucket, connect, job_key, job_subject, new_id, FleetError, FleetJob, FleetMachine, Submission,
};
use crate::core::intake::JobSpec;
use crate::core::store::now_ms;
use async_nats::jetstream::{self, message::PublishMessage};
use futures::StreamExt;
use std::path::Path;

/// A connection to the fleet.
pub struct FleetClient {
    js: jetstream::Context,
    kv: jetstream::kv::Store,
}

impl FleetClient {
    pub async fn connect(url: &str, credentials: Option<&Path>) -> Result<FleetClient, FleetError> {
        let client = connect(url, credentials, "machlink-client").await?;
        let js = jetstream::new(client);
        let kv = bucket(&js).await?;
        Ok(FleetClient { js, kv })
    }

    async fn read<T: serde::de::DeserializeOwned>(
        &self,
        prefix: &str,
    ) -> Result<Vec<T>, FleetError> {
        let mut keys = self
            .kv
            .keys()
            .await
            .map_err(|e| FleetError::js("listing the fleet's view", e))?;
        let mut names = Vec::new();
        while let Some(k) = keys.next().await {
            let k = k.map_err(|e| FleetError::js("listing the fleet's view", e))?;
            if k.starts_with(prefix) {
                names.push(k);
            }
        }
        names.sort();
        let mut out = Vec::new();
        for k in names {
            let Some(v) = self
                .kv
                .get(k.as_str())
                .await
                .map_err(|e| FleetError::js(format!("reading {k}"), e))?
            else {
                continue; // deleted meanwhile
            };
            out.push(serde_json::from_slice(&v).map_err(|e| FleetError::Corrupt {
                key: k.clone(),
                message: e.to_string(),
            })?);
        }
        Ok(out)
    }

    /// Every machine some daemon of the fleet has announced.
    pub async fn machines(&self) -> Result<Vec<FleetMachine>, FleetError> {
        self.read("machine.").await
    }

    /// Every job of the fleet, oldest first.
    pub async fn jobs(&self) -> Result<Vec<FleetJob>, FleetError> {
        let mut jobs: Vec<FleetJob> = self.read("job.").await?;
        jobs.sort_by(|a, b| a.id.cmp(&b.id));
        Ok(jobs)
    }

    /// Puts a job on the queue of its machine's group; the daemon that owns the machine
    /// plans, checks and stores it. Returns the job as the fleet shows it (`submitted`).
    pub async fn submit(&self, spec: &JobSpec) -> Result<FleetJob, FleetError> {
        let machine = spec
            .machine
            .clone()
            .ok_or_else(|| FleetError::UnknownMachine {
                machine: String::new(),
                known: "the job names none".into(),
            })?;
        let entry = self
            .kv
            .get(super::machine_key(&machine))
            .await
            .map_err(|e| FleetError::js("reading the fleet's machines", e))?;
        let Some(entry) = entry else {
            let known: Vec<String> = self.machines().await?.into_iter().map(|m| m.name).collect();
            return Err(FleetError::UnknownMachine {
                machine,
                known: if known.is_empty() {
                    "none yet".into()
                } else {
                    known.join(", ")
                },
            });
        };
        let m: FleetMachine = serde_json::from_slice(&entry).map_err(|e| FleetError::Corrupt {
            key: super::machine_key(&machine),
            message: e.to_string(),
        })?;
        let id = new_id();
        let job = FleetJob {
            id: id.clone(),
            machine: machine.clone(),
            state: "submitted".into(),
            daemon: None,
            local_id: None,
            acked: 0,
            total: 0,
            error: None,
            file_name: spec.input.file_name.clone(),
            updated_ms: now_ms(),
        };
        let bytes = serde_json::to_vec(&job).map_err(|e| FleetError::js("a job", e))?;
        self.kv
            .create(job_key(&id), bytes.into())
            .await
            .map_err(|e| FleetError::js(format!("recording job {id}"), e))?;
        let payload = serde_json::to_vec(&Submission {
            id: id.clone(),
            spec: spec.clone(),
            submitted_ms: now_ms(),
        })
        .map_err(|e| FleetError::js("a job", e))?;
        self.js
            .send_publish(
                job_subject(&m.group, &machine),
                PublishMessage::build()
                    .payload(payload.into())
                    .message_id(&id),
            )
            .await
            .map_err(|e| FleetError::js(format!("job {id}"), e))?
            .await
            .map_err(|e| FleetError::js(format!("job {id}"), e))?;
        Ok(job)
    }
}
