//! A pseudo-terminal whose master end is an async byte stream: the simulated machine's serial port.

use nix::fcntl::{fcntl, FcntlArg, OFlag};
use nix::pty::{grantpt, posix_openpt, ptsname_r, unlockpt};
use nix::sys::termios::{cfmakeraw, tcgetattr, tcsetattr, SetArg};
use std::fs::File;
use std::io::{self, Read, Write};
use std::os::fd::{FromRawFd, IntoRawFd, OwnedFd};
use std::os::unix::fs::OpenOptionsExt;
use std::pin::Pin;
use std::task::{ready, Context, Poll};
use tokio::io::unix::AsyncFd;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};

/// The machine's end of a pty. The slave end stays open inside so the line never hangs up
/// while a host closes and reopens it.
pub struct PtyPort {
    master: AsyncFd<File>,
    _slave: File,
    /// The path a host opens, e.g. /dev/pts/7.
    pub slave_path: String,
}

impl PtyPort {
    /// Opens a new pty in raw mode (no echo, no line editing). Must run inside a tokio runtime.
    pub fn open() -> io::Result<PtyPort> {
        let master = posix_openpt(OFlag::O_RDWR | OFlag::O_NOCTTY).map_err(io::Error::from)?;
        grantpt(&master).map_err(io::Error::from)?;
        unlockpt(&master).map_err(io::Error::from)?;
        let slave_path = ptsname_r(&master).map_err(io::Error::from)?;
        let slave = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .custom_flags(libc_o_noctty())
            .open(&slave_path)?;
        let mut t = tcgetattr(&slave).map_err(io::Error::from)?;
        cfmakeraw(&mut t);
        tcsetattr(&slave, SetArg::TCSANOW, &t).map_err(io::Error::from)?;
        // SAFETY: the raw fd comes straight from the PtyMaster we own and give up here.
        let fd = unsafe { OwnedFd::from_raw_fd(master.into_raw_fd()) };
        fcntl(&fd, FcntlArg::F_SETFL(OFlag::O_NONBLOCK | OFlag::O_RDWR))
            .map_err(io::Error::from)?;
        // SAFETY: a std File owns its fd and always returns that same, open fd.
        let master = unsafe { AsyncFd::register(File::from(fd)) }.map_err(io::Error::from)?;
        Ok(PtyPort {
            master,
            _slave: slave,
            slave_path,
        })
    }
}

fn libc_o_noctty() -> i32 {
    OFlag::O_NOCTTY.bits()
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
