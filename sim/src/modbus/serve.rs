//! The simulated device's two servers: Modbus TCP (a task per connection) and RTU on any byte stream with a model of the line's timing, both injecting the configured faults.

use super::{lock, Reply, Shared};
use crate::line;
use machlink_protocols::modbus::frame::{self, exception, FrameError, Request, Response, Side};
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::time::Instant;

/// What the device does with one request, its faults decided.
enum Plan {
    /// Carried out (or refused with an exception); answered, perhaps late.
    Answer { reply: Reply, late: bool },
    /// Carried out, never answered.
    Silent,
    /// TCP: carried out, then the connection is closed. RTU: lost, and the device goes deaf.
    Disconnect,
}

impl Shared {
    /// Numbers the request and decides its fate (docs: `Faults`).
    fn plan(&self, req: Result<Request, FrameError>, rtu: bool) -> (u64, Plan) {
        let n = self.request_no.fetch_add(1, Ordering::SeqCst) + 1;
        lock(&self.stats).requests = n;
        if self.silent() {
            // hung: the request is lost, neither carried out nor answered
            lock(&self.stats).dropped += 1;
            return (n, Plan::Silent);
        }
        let f = &self.cfg.faults;
        if let Some(&(_, code)) = f.exceptions.iter().find(|e| e.0 == n) {
            lock(&self.stats).exceptions += 1;
            return (
                n,
                Plan::Answer {
                    reply: Err(code),
                    late: false,
                },
            );
        }
        let Ok(req) = req else {
            // A malformed PDU (a byte count that disagrees with its quantity).
            let reply = Err(exception::ILLEGAL_VALUE);
            return (n, Plan::Answer { reply, late: false });
        };
        if f.disconnects.contains(&n) {
            lock(&self.stats).disconnects += 1;
            if !rtu {
                let _ = self.apply(&req);
            }
            return (n, Plan::Disconnect);
        }
        let reply = self.apply(&req);
        if f.drop_replies.contains(&n) {
            lock(&self.stats).dropped += 1;
            return (n, Plan::Silent);
        }
        let late = f.late_replies.contains(&n);
        if late {
            lock(&self.stats).late += 1;
        }
        (n, Plan::Answer { reply, late })
    }

    /// Counts a frame on the wire.
    fn on_wire(&self, bytes: usize) {
        let mut s = lock(&self.stats);
        s.wire_bytes += bytes as u64;
        s.frames += 1;
    }
}

fn reply_pdu(req_function: u8, reply: &Reply) -> Vec<u8> {
    match reply {
        Ok(r) => r.pdu(),
        Err(code) => Response::Exception {
            function: req_function & !frame::function::EXCEPTION,
            code: *code,
        }
        .pdu(),
    }
}

/// Accepts connections until the listener fails; each is served by its own task.
pub(super) async fn tcp(listener: TcpListener, shared: Arc<Shared>) {
    loop {
        let Ok((stream, _)) = listener.accept().await else {
            tokio::time::sleep(Duration::from_millis(10)).await;
            continue;
        };
        let _ = stream.set_nodelay(true);
        lock(&shared.stats).connections += 1;
        tokio::spawn(tcp_connection(stream, Arc::clone(&shared)));
    }
}

/// One TCP connection: requests in order, each answered before the next is read.
async fn tcp_connection(mut stream: TcpStream, shared: Arc<Shared>) {
    let mut buf = Vec::new();
    let mut tmp = [0u8; 2048];
    loop {
        while let Some(split) = frame::tcp_split(&buf) {
            let Ok((f, n)) = split else { return };
            buf.drain(..n);
            let arrived = Instant::now();
            shared.on_wire(n);
            let function = f.pdu.first().copied().unwrap_or(0);
            // On TCP, unit 255 means "the device behind this address" (no gateway).
            let (req_no, plan) = if f.unit == shared.cfg.unit_id || f.unit == 255 {
                shared.plan(Request::from_pdu(&f.pdu), false)
            } else {
                let reply = Err(exception::GATEWAY_TARGET);
                (0, Plan::Answer { reply, late: false })
            };
            let reply = match plan {
                Plan::Answer { reply, late } => {
                    if late {
                        tokio::time::sleep_until(arrived + shared.cfg.faults.late_by).await;
                    }
                    reply
                }
                Plan::Silent => {
                    pace_tcp(&shared, n, 0).await;
                    continue;
                }
                Plan::Disconnect => return,
            };
            let pdu = reply_pdu(function, &reply);
            let bytes = frame::tcp_encode(f.transaction, f.unit, &pdu);
            shared.on_wire(bytes.len());
            pace_tcp(&shared, n, bytes.len()).await;
            if stream.write_all(&bytes).await.is_err() {
                return;
            }
            lock(&shared.replies).push(req_no);
        }
        match stream.read(&mut tmp).await {
            Ok(0) | Err(_) => return,
            Ok(n) => buf.extend_from_slice(&tmp[..n]),
        }
    }
}

/// TCP at `line_baud`: the exchange takes what it would on a serial line (RTU frames are
/// 4 bytes shorter than MBAP ones; 3.5 characters of silence after each).
async fn pace_tcp(shared: &Shared, request: usize, reply: usize) {
    let Some(baud) = shared.cfg.line_baud else {
        return;
    };
    let rtu = |tcp: usize| {
        if tcp == 0 {
            0.0
        } else {
            tcp as f64 - 4.0 + 3.5
        }
    };
    tokio::time::sleep(line::chars(baud, rtu(request) + rtu(reply))).await;
}

/// The RTU slave: frames from `io` in order, each answered (or not) before the next.
///
/// With `line_baud` the device keeps the line's clock: a request occupies the line from
/// when its first byte arrived (or from 3.5 characters after the previous frame, if that is
/// later) for its bytes' time; the reply starts 3.5 characters after the request ends and
/// is written out when its last byte would have arrived.
pub(super) async fn rtu<S>(io: S, shared: Arc<Shared>)
where
    S: AsyncRead + AsyncWrite + Unpin,
{
    let (mut rd, mut wr) = tokio::io::split(io);
    let baud = shared.cfg.line_baud;
    let chars = |n: f64| baud.map_or(Duration::ZERO, |b| line::chars(b, n));
    let mut buf: Vec<u8> = Vec::new();
    let mut tmp = [0u8; 1024];
    // When the first byte of the frame at the front of `buf` arrived.
    let mut first: Option<Instant> = None;
    // The line's clock: when the last frame on it ended.
    let mut line_free = Instant::now();
    let mut deaf_until: Option<Instant> = None;
    let paused = line::clock_is_paused();
    loop {
        let (f, len) = match frame::rtu_split(&buf, Side::Request) {
            None => {
                match rd.read(&mut tmp).await {
                    Ok(0) | Err(_) => return,
                    Ok(n) => {
                        if buf.is_empty() {
                            first = Some(Instant::now());
                        }
                        buf.extend_from_slice(&tmp[..n]);
                    }
                }
                continue;
            }
            Some((Err(FrameError::UnknownFunction(_)), _)) => {
                // A function this map does not know: its frame ends where the line falls
                // silent for 3.5 characters.
                let quiet = chars(3.5).max(Duration::from_millis(2));
                loop {
                    match tokio::time::timeout(quiet, rd.read(&mut tmp)).await {
                        Ok(Ok(0)) | Ok(Err(_)) => return,
                        Ok(Ok(n)) => buf.extend_from_slice(&tmp[..n]),
                        Err(_) => break,
                    }
                }
                let bytes = std::mem::take(&mut buf);
                let len = bytes.len();
                let n = len.saturating_sub(2);
                if len < 4
                    || frame::crc16(&bytes[..n]) != u16::from_le_bytes([bytes[n], bytes[n + 1]])
                {
                    first = None;
                    continue;
                }
                let f = frame::RtuFrame {
                    unit: bytes[0],
                    pdu: bytes[1..n].to_vec(),
                };
                (f, len)
            }
            Some((Err(_), n)) => {
                // A damaged frame: a device ignores it (the host times out).
                buf.drain(..n);
                first = (!buf.is_empty()).then(Instant::now);
                continue;
            }
            Some((Ok(f), n)) => {
                buf.drain(..n);
                (f, n)
            }
        };
        let arrived = first.take().unwrap_or_else(Instant::now);
        if !buf.is_empty() {
            first = Some(Instant::now());
        }
        shared.on_wire(len);
        let start = if baud.is_some() {
            arrived.max(line_free + chars(3.5))
        } else {
            arrived
        };
        let end = start + chars(len as f64);
        line_free = end;
        if deaf_until.is_some_and(|d| start < d) {
            shared.request_no.fetch_add(1, Ordering::SeqCst);
            lock(&shared.stats).requests = shared.request_no.load(Ordering::SeqCst);
            continue;
        }
        if f.unit != shared.cfg.unit_id {
            continue; // another slave's request (or a broadcast): not ours to answer
        }
        let function = f.pdu.first().copied().unwrap_or(0);
        let (req_no, plan) = shared.plan(Request::from_pdu(&f.pdu), true);
        let (reply, late) = match plan {
            Plan::Answer { reply, late } => (reply, late),
            Plan::Silent => continue,
            Plan::Disconnect => {
                deaf_until = Some(end + shared.cfg.faults.silence);
                continue;
            }
        };
        let bytes = frame::rtu_encode(f.unit, &reply_pdu(function, &reply));
        let on_time = end + chars(3.5 + bytes.len() as f64);
        let due = if late {
            on_time.max(start + shared.cfg.faults.late_by)
        } else {
            on_time
        };
        line::sleep_until_precise(due, paused).await;
        if wr.write_all(&bytes).await.is_err() || wr.flush().await.is_err() {
            return;
        }
        shared.on_wire(bytes.len());
        lock(&shared.replies).push(req_no);
        line_free = due;
    }
}
