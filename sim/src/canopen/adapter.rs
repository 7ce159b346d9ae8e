//! A simulated USB-CAN adapter speaking SLCAN on a pty, in front of an in-memory bus: the
//! adapter's side of the one SLCAN codec (`machlink_protocols::canopen::slcan`).

use crate::sewing::pty::PtyPort;
use machlink_protocols::canopen::slcan::{encode_frame, LineDecoder, SlcanLine};
use machlink_protocols::canopen::{CanBus, CanFrame, MemoryBus};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::mpsc;
use tokio::task::JoinHandle;

/// The adapter's state and its answers to the host, with no I/O.
#[derive(Debug, Default)]
pub struct SlcanAdapter {
    open: bool,
    listen_only: bool,
    bitrate: Option<u32>,
}

impl SlcanAdapter {
    pub fn new() -> SlcanAdapter {
        SlcanAdapter::default()
    }

    /// Whether frames from the bus go to the host.
    pub fn is_open(&self) -> bool {
        self.open
    }

    /// The bit rate the host set.
    pub fn bitrate(&self) -> Option<u32> {
        self.bitrate
    }

    /// Answers one line from the host (appended to `reply`); a frame it should transmit is
    /// returned.
    pub fn on_line(&mut self, line: SlcanLine, reply: &mut Vec<u8>) -> Option<CanFrame> {
        const OK: &[u8] = b"\r";
        const BEL: &[u8] = b"\x07";
        match line {
            SlcanLine::Bitrate(b) if !self.open => {
                self.bitrate = Some(b);
                reply.extend_from_slice(OK);
            }
            SlcanLine::Open | SlcanLine::ListenOnly if !self.open => {
                self.open = true;
                self.listen_only = line == SlcanLine::ListenOnly;
                reply.extend_from_slice(OK);
            }
            SlcanLine::Close if self.open => {
                self.open = false;
                reply.extend_from_slice(OK);
            }
            SlcanLine::Frame(f) if self.open && !self.listen_only => {
                reply.extend_from_slice(if f.is_extended() { b"Z\r" } else { b"z\r" });
                return Some(f);
            }
            SlcanLine::Ok => reply.extend_from_slice(OK),
            SlcanLine::Other(t) if t == "V" => reply.extend_from_slice(b"V1013\r"),
            SlcanLine::Other(t) if t == "N" => reply.extend_from_slice(b"NML01\r"),
            SlcanLine::Other(t) if t == "F" => reply.extend_from_slice(b"F00\r"),
            // the host's own answers are not commands
            SlcanLine::Queued | SlcanLine::Error => {}
            _ => reply.extend_from_slice(BEL),
        }
        None
    }
}

/// An adapter running on a pty; stops when dropped.
pub struct AdapterHandle {
    /// The pty a host opens as the adapter's serial port.
    pub path: String,
    tasks: Vec<JoinHandle<()>>,
}

impl Drop for AdapterHandle {
    fn drop(&mut self) {
        for t in &self.tasks {
            t.abort();
        }
    }
}

/// Puts an SLCAN adapter for `bus` on a new pty. Must run inside a tokio runtime.
pub fn spawn_adapter(bus: &MemoryBus) -> std::io::Result<AdapterHandle> {
    let pty = PtyPort::open()?;
    let path = pty.slave_path.clone();
    let (mut rd, mut wr) = tokio::io::split(pty);
    let (tx, mut rx) = mpsc::unbounded_channel::<Vec<u8>>();
    let writer = tokio::spawn(async move {
        while let Some(bytes) = rx.recv().await {
            if wr.write_all(&bytes).await.is_err() {
                return;
            }
        }
    });
    let open = Arc::new(AtomicBool::new(false));
    let mut from_bus = bus.attach();
    let port = from_bus.sender();
    let (tx1, open1) = (tx.clone(), open.clone());
    let host = tokio::spawn(async move {
        let mut adapter = SlcanAdapter::new();
        let mut decoder = LineDecoder::new();
        let mut lines = Vec::new();
        let mut buf = [0u8; 1024];
        loop {
            let n = match rd.read(&mut buf).await {
                Ok(0) | Err(_) => return,
                Ok(n) => n,
            };
            decoder.push(&buf[..n], &mut lines);
            let mut reply = Vec::new();
            for line in lines.drain(..) {
                let frame = adapter.on_line(line, &mut reply);
                // open before the frame goes out: a host that opens the channel and sends a
                // request in one write must get the answer (once the flag was stored after
                // the whole batch, and a drive's quick reply was dropped as if closed)
                open1.store(adapter.is_open(), Ordering::SeqCst);
                if let Some(f) = frame {
                    port.send_now(&f);
                }
            }
            if !reply.is_empty() && tx1.send(reply).is_err() {
                return;
            }
        }
    });
    let bus_side = tokio::spawn(async move {
        let mut line = Vec::with_capacity(32);
        while let Ok(f) = from_bus.recv().await {
            if open.load(Ordering::SeqCst) {
                line.clear();
                encode_frame(&f, &mut line);
                if tx.send(line.clone()).is_err() {
                    return;
                }
            }
        }
    });
    Ok(AdapterHandle {
        path,
        tasks: vec![writer, host, bus_side],
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_adapter_answers_as_lawicel_says() {
        let mut a = SlcanAdapter::new();
        let mut r = Vec::new();
        let f = CanFrame::new(0x080, &[]).unwrap();
        assert_eq!(
            a.on_line(SlcanLine::Frame(f), &mut r),
            None,
            "closed: no transmit"
        );
        assert_eq!(a.on_line(SlcanLine::Bitrate(500_000), &mut r), None);
        a.on_line(SlcanLine::Open, &mut r);
        a.on_line(SlcanLine::Bitrate(1_000_000), &mut r);
        assert_eq!(a.on_line(SlcanLine::Frame(f), &mut r), Some(f));
        a.on_line(SlcanLine::Close, &mut r);
        a.on_line(SlcanLine::Close, &mut r);
        assert_eq!(r, b"\x07\r\r\x07z\r\r\x07");
        assert_eq!(a.bitrate(), Some(500_000));
    }

    /// A host that opens the channel and sends its first request in one write (as python-can
    /// does with `sleep_after_open=0`) gets the answer, however fast the drive replies.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_request_sent_with_the_open_command_is_answered() {
        use machlink_protocols::canopen::CanBus;
        use tokio_serial::SerialPortBuilderExt;
        for round in 0..40u8 {
            let bus = MemoryBus::new();
            let mut drive = bus.attach();
            tokio::spawn(async move {
                while let Ok(f) = drive.recv().await {
                    let reply = CanFrame::new(0x581, f.data()).unwrap();
                    drive.send_now(&reply);
                }
            });
            let adapter = spawn_adapter(&bus).unwrap();
            let mut host = tokio_serial::new(&adapter.path, 115_200)
                .open_native_async()
                .unwrap();
            let mut request = b"S8\rO\r".to_vec();
            encode_frame(
                &CanFrame::new(0x601, &[0x40, 0x00, 0x10, 0x00, round, 0, 0, 0]).unwrap(),
                &mut request,
            );
            host.write_all(&request).await.unwrap();
            let mut want = Vec::new();
            encode_frame(
                &CanFrame::new(0x581, &[0x40, 0x00, 0x10, 0x00, round, 0, 0, 0]).unwrap(),
                &mut want,
            );
            let mut got = Vec::new();
            let found = tokio::time::timeout(std::time::Duration::from_secs(2), async {
                let mut buf = [0u8; 256];
                loop {
                    let n = host.read(&mut buf).await.unwrap();
                    got.extend_from_slice(&buf[..n]);
                    if got.windows(want.len()).any(|w| w == want) {
                        return;
                    }
                }
            })
            .await;
            assert!(
                found.is_ok(),
                "round {round}: no answer to the first request, the host read {:?}",
                String::from_utf8_lossy(&got)
            );
        }
    }
}
