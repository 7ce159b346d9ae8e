//! A pseudo-terminal whose master end is an async byte stream: the simulated machine's serial port.

use std::fs::File;
use std::io::{self, Read, Write};
use std::os::fd::OwnedFd;
use std::pin::Pin;
use std::task::{ready, Context, Poll};
use tokio::io::unix::AsyncFd;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};

/// The machine's end of a pty (see `crate::pty`). The slave end stays open inside so the line
/// never hangs up while a host closes and reopens it.
pub struct PtyPort {
    master: AsyncFd<File>,
    _slave: OwnedFd,
    /// The path a host opens, e.g. /dev/pts/7.
    pub slave_path: String,
}

impl PtyPort {
    /// Opens a new raw pty. Must run inside a tokio runtime.
    pub fn open() -> io::Result<PtyPort> {
        let pty = crate::pty::Pty::open()?;
        // SAFETY: a std File owns its fd and always returns that same, open fd.
        let master =
            unsafe { AsyncFd::register(File::from(pty.master)) }.map_err(io::Error::from)?;
        Ok(PtyPort {
            master,
            _slave: pty.slave,
            slave_path: pty.path.display().to_string(),
        })
    }
}

impl AsyncRead for PtyPort {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        loop {
            let mut guard = ready!(self.master.poll_read_ready(cx))?;
            let unfilled = buf.initialize_unfilled();
            match guard.try_io(|f| f.get_ref().read(unfilled)) {
                Ok(Ok(n)) => {
                    buf.advance(n);
                    return Poll::Ready(Ok(()));
                }
                Ok(Err(e)) => return Poll::Ready(Err(e)),
                Err(_would_block) => continue,
            }
        }
    }
}

impl AsyncWrite for PtyPort {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        data: &[u8],
    ) -> Poll<io::Result<usize>> {
        loop {
            let mut guard = ready!(self.master.poll_write_ready(cx))?;
            match guard.try_io(|f| f.get_ref().write(data)) {
                Ok(r) => return Poll::Ready(r),
                Err(_would_block) => continue,
            }
        }
    }
    fn poll_flush(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }
    fn poll_shutdown(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }
}
