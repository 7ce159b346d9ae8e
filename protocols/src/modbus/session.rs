//! A session with one Modbus device: has its transport opened (or takes a stream handed in), gives every request a timeout, reopens after failures, and paces retries with backoff.

use super::frame::{Request, Response};
use super::settings::ModbusError;
use super::transport::{
    Barrier, ByteStream, Endpoint, Framing, ReplyFate, Wire, WireCounters, WireError,
};
use std::time::Duration;

/// How the session reaches its device.
pub enum Dial {
    /// Opened (and opened again after a failure) by the transport.
    Open(Endpoint),
    /// A stream that is already open; it is used as it is and never reopened.
    Given(Option<Box<dyn ByteStream>>, Framing),
}

/// What the session needs beyond where the device is.
#[derive(Clone, Copy, Debug)]
pub struct SessionTiming {
    /// How long one request may wait for its reply (and a TCP connect for its connection).
    pub timeout: Duration,
    /// RTU: how long the line must be silent before a request after a timeout.
    pub quiet: Duration,
}

/// One device's connection, opened on first use and again after it failed.
pub struct Session {
    dial: Dial,
    unit: u8,
    timing: SessionTiming,
    barrier: Option<Barrier>,
    target: String,
    wire: Option<Wire>,
    opens: u64,
    record: bool,
    /// Counters and reply fates of wires closed before the current one.
    past: WireCounters,
    past_replies: Vec<ReplyFate>,
}

impl Session {
    /// `target` names the device in errors ("Modbus device 10.0.0.7:502 unit 1").
    pub fn new(
        dial: Dial,
        unit: u8,
        timing: SessionTiming,
        barrier: Option<Barrier>,
        target: String,
    ) -> Session {
        Session {
            dial,
            unit,
            timing,
            barrier,
            target,
            wire: None,
            opens: 0,
            record: false,
            past: WireCounters::default(),
            past_replies: Vec::new(),
        }
    }

    pub fn target(&self) -> &str {
        &self.target
    }
    /// How often the transport was opened (the first time included).
    pub fn opens(&self) -> u64 {
        self.opens
    }
    /// What every wire of this session did, summed.
    pub fn counters(&self) -> WireCounters {
        let mut c = self.past;
        if let Some(w) = &self.wire {
            let n = w.counters();
            c.requests += n.requests;
            c.replies += n.replies;
            c.stale += n.stale;
            c.drained += n.drained;
            c.barriers += n.barriers;
        }
        c
    }
    /// Records the fate of every reply frame from now on (see [`Session::replies`]).
    pub fn record_replies(&mut self) {
        self.record = true;
        if let Some(w) = &mut self.wire {
            w.record_replies();
        }
    }
    /// Every reply frame's fate, requests numbered over the whole session (from 1).
    pub fn replies(&self) -> Vec<ReplyFate> {
        let mut v = self.past_replies.clone();
        if let Some(w) = &self.wire {
            let base = self.past.requests;
            v.extend(w.replies().iter().map(|f| match *f {
                ReplyFate::Taken { request } => ReplyFate::Taken {
                    request: request + base,
                },
                other => other,
            }));
        }
        v
    }

    /// Sends `req` and returns its reply; an exception reply is `ModbusError::Exception`.
    /// `what` names the request in errors ("read of holding registers 0..=15").
    pub async fn call(&mut self, req: &Request, what: &str) -> Result<Response, ModbusError> {
        if self.wire.is_none() {
            self.open().await?;
        }
        let Some(wire) = self.wire.as_mut() else {
            unreachable!("open() either sets the wire or fails")
        };
        let keep_after_timeout = wire.framing() != Framing::Tcp;
        let result = wire.exchange(req, self.timing.timeout).await;
        let target = self.target.clone();
        let what = what.to_string();
        match result {
            Ok(Response::Exception { code, .. }) => {
                Err(ModbusError::Exception { target, what, code })
            }
            Ok(r) => Ok(r),
            // RTU keeps its port: the wire settles the line before the next request.
            Err(e @ (WireError::Timeout(_) | WireError::Garbled(_))) => {
                if !keep_after_timeout {
                    self.close();
                }
                Err(match e {
                    WireError::Timeout(after) => ModbusError::Timeout {
                        target,
                        what,
                        after,
                    },
                    other => ModbusError::BadReply {
                        target,
                        what,
                        detail: other.to_string(),
                    },
                })
            }
            Err(WireError::NoBarrier) => Err(ModbusError::BadReply {
                target,
                what,
                detail: WireError::NoBarrier.to_string(),
            }),
            Err(e @ (WireError::Closed | WireError::Io(_))) => {
                self.close();
                let source = match e {
                    WireError::Io(io) => io,
                    _ => std::io::ErrorKind::UnexpectedEof.into(),
                };
                Err(ModbusError::Transport {
                    target,
                    what,
                    source,
                })
            }
        }
    }

    /// Drops the wire; the next call opens the transport again.
    fn close(&mut self) {
        if let Some(w) = self.wire.take() {
            let n = w.counters();
            let base = self.past.requests;
            self.past_replies
                .extend(w.replies().iter().map(|f| match *f {
                    ReplyFate::Taken { request } => ReplyFate::Taken {
                        request: request + base,
                    },
                    other => other,
                }));
            self.past.requests += n.requests;
            self.past.replies += n.replies;
            self.past.stale += n.stale;
            self.past.drained += n.drained;
            self.past.barriers += n.barriers;
        }
    }

    async fn open(&mut self) -> Result<(), ModbusError> {
        let target = self.target.clone();
        let failed = |source: std::io::Error| ModbusError::Connect {
            target: target.clone(),
            source,
        };
        let (io, framing): (Box<dyn ByteStream>, Framing) = match &mut self.dial {
            Dial::Open(endpoint) => {
                let io = endpoint.open(self.timing.timeout).await.map_err(failed)?;
                (io, endpoint.framing())
            }
            Dial::Given(io, framing) => match io.take() {
                Some(io) => (io, *framing),
                None => {
                    return Err(failed(std::io::Error::new(
                        std::io::ErrorKind::NotConnected,
                        "the stream handed to the link has closed, and a handed-in stream is never reopened",
                    )))
                }
            },
        };
        let mut wire = Wire::new(io, framing, self.unit, self.timing.quiet, self.barrier);
        if self.record {
            wire.record_replies();
        }
        self.wire = Some(wire);
        self.opens += 1;
        Ok(())
    }
}

/// Waits between failed attempts: `initial`, doubling up to `max`; gives up after more than
/// `retries` failures in a row.
#[derive(Clone, Copy, Debug)]
pub struct Backoff {
    pub initial: Duration,
    pub max: Duration,
    pub retries: u32,
    failures: u32,
}

impl Backoff {
    pub fn new(initial: Duration, max: Duration, retries: u32) -> Backoff {
        Backoff {
            initial,
            max,
            retries,
            failures: 0,
        }
    }
    /// A success: the next failure waits `initial` again.
    pub fn reset(&mut self) {
        self.failures = 0;
    }
    /// A failure: how long to wait before trying again, or `None` once the retries are spent.
    pub fn failed(&mut self) -> Option<Duration> {
        self.failures += 1;
        if self.failures > self.retries {
            return None;
        }
        Some(
            self.initial
                .saturating_mul(1 << (self.failures - 1).min(16))
                .min(self.max),
        )
    }
    /// Failures in a row so far.
    pub fn failures(&self) -> u32 {
        self.failures
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backoff_doubles_to_its_ceiling_and_gives_up_after_the_retries() {
        let mut b = Backoff::new(Duration::from_millis(50), Duration::from_millis(300), 4);
        let waits: Vec<_> = std::iter::from_fn(|| b.failed()).collect();
        assert_eq!(
            waits,
            [50, 100, 200, 300].map(Duration::from_millis).to_vec()
        );
        assert_eq!(b.failures(), 5);
        b.reset();
        assert_eq!(b.failed(), Some(Duration::from_millis(50)));
    }

    #[tokio::test]
    async fn a_handed_in_stream_is_never_reopened() {
        let (host, dev) = tokio::io::duplex(64);
        drop(dev);
        let mut s = Session::new(
            Dial::Given(Some(Box::new(host)), Framing::Tcp),
            1,
            SessionTiming {
                timeout: Duration::from_millis(50),
                quiet: Duration::ZERO,
            },
            None,
            "test device".into(),
        );
        let req = Request::Read { addr: 0, count: 1 };
        let first = s.call(&req, "read").await.unwrap_err();
        assert!(matches!(first, ModbusError::Transport { .. }), "{first}");
        let second = s.call(&req, "read").await.unwrap_err().to_string();
        assert!(second.contains("never reopened"), "{second}");
        assert_eq!(s.opens(), 1);
    }
}
