//! The one way simulators get a serial port: a raw pseudo-terminal, seen blocking (threads) or async (tokio), optionally behind a symlink.
//!
//! `Pty::open` makes the pair; a device reads and writes the master end, clients open `path`.
//! `Pty::blocking` hands threads (the GRBL simulator) two clones of the master;
//! `PtyPort` is the same master as a tokio byte stream (sewing, Modbus RTU and CAN
//! simulators); `PtyLink` is the symbolic link a command line asks for.

use nix::fcntl::{fcntl, FcntlArg, OFlag};
use nix::poll::{poll, PollFd, PollFlags, PollTimeout};
use nix::sys::termios::{cfmakeraw, tcgetattr, tcsetattr, SetArg};
use std::fs::File;
use std::io::{self, Read, Write};
use std::os::fd::{AsFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::pin::Pin;
use std::task::{ready, Context, Poll};
use std::time::Duration;
use tokio::io::unix::AsyncFd;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};

/// A pty pair in raw mode. The device side reads and writes `master`; clients open `path`.
/// The slave stays open here so the master never sees a hang-up between clients.
pub struct Pty {
    pub master: OwnedFd,
    pub slave: OwnedFd,
    pub path: PathBuf,
}

impl Pty {
    /// Opens a raw, non-blocking pty pair.
    pub fn open() -> io::Result<Pty> {
        let r = nix::pty::openpty(None, None).map_err(io::Error::from)?;
        let mut t = tcgetattr(&r.slave).map_err(io::Error::from)?;
        cfmakeraw(&mut t);
        tcsetattr(&r.slave, SetArg::TCSANOW, &t).map_err(io::Error::from)?;
        fcntl(&r.master, FcntlArg::F_SETFL(OFlag::O_NONBLOCK)).map_err(io::Error::from)?;
        let path = nix::unistd::ttyname(&r.slave).map_err(io::Error::from)?;
        Ok(Pty {
            master: r.master,
            slave: r.slave,
            path,
        })
    }

    /// The blocking view: a reader and a writer on the (non-blocking) master, for threads
    /// that wait with [`wait_ready`].
    pub fn blocking(&self) -> io::Result<(File, File)> {
        Ok((
            File::from(self.master.try_clone()?),
            File::from(self.master.try_clone()?),
        ))
    }

    /// The async view of the master. Must run inside a tokio runtime.
    pub fn into_async(self) -> io::Result<PtyPort> {
        // SAFETY: a std File owns its fd and always returns that same, open fd.
        let master =
            unsafe { AsyncFd::register(File::from(self.master)) }.map_err(io::Error::from)?;
        Ok(PtyPort {
            master,
            _slave: self.slave,
            slave_path: self.path.display().to_string(),
        })
    }
}

/// Waits until `fd` is readable (or writable when `write`), at most `timeout`; true when ready.
pub fn wait_ready(fd: impl AsFd, write: bool, timeout: Duration) -> io::Result<bool> {
    let flags = if write {
        PollFlags::POLLOUT
    } else {
        PollFlags::POLLIN
    };
    let mut fds = [PollFd::new(fd.as_fd(), flags)];
    let ms = timeout.as_millis().min(u16::MAX as u128) as u16;
    match poll(&mut fds, PollTimeout::from(ms)) {
        Ok(n) => Ok(n > 0),
        Err(nix::errno::Errno::EINTR) => Ok(false),
        Err(e) => Err(e.into()),
    }
}

/// Makes `link` a symbolic link to `target`, replacing an old link (never a regular file).
pub fn symlink_replacing(target: &Path, link: &Path) -> io::Result<()> {
    if let Ok(meta) = std::fs::symlink_metadata(link) {
        if meta.file_type().is_symlink() {
            std::fs::remove_file(link)?;
        } else {
            return Err(io::Error::new(
                io::ErrorKind::AlreadyExists,
                format!("{} exists and is not a symbolic link", link.display()),
            ));
        }
    }
    std::os::unix::fs::symlink(target, link)
}

/// A symbolic link to a simulator's pty (an old link of that name is replaced), removed
/// again when dropped if it still points at that pty.
#[derive(Debug)]
pub struct PtyLink {
    link: PathBuf,
    target: PathBuf,
}

impl PtyLink {
    pub fn new(target: &Path, link: &Path) -> io::Result<PtyLink> {
        symlink_replacing(target, link)?;
        Ok(PtyLink {
            link: link.to_path_buf(),
            target: target.to_path_buf(),
        })
    }
    /// `Some(PtyLink)` when a link was asked for.
    pub fn optional(target: &Path, link: Option<&Path>) -> io::Result<Option<PtyLink>> {
        link.map(|l| PtyLink::new(target, l)).transpose()
    }
    pub fn path(&self) -> &Path {
        &self.link
    }
}

impl Drop for PtyLink {
    fn drop(&mut self) {
        if std::fs::read_link(&self.link).is_ok_and(|t| t == self.target) {
            let _ = std::fs::remove_file(&self.link);
        }
    }
}

/// The async view of a pty's master: the simulated machine's serial port. The slave end
/// stays open inside so the line never hangs up while a host closes and reopens it.
pub struct PtyPort {
    master: AsyncFd<File>,
    _slave: OwnedFd,
    /// The path a host opens, e.g. /dev/pts/7.
    pub slave_path: String,
}

impl PtyPort {
    /// Opens a new raw pty. Must run inside a tokio runtime.
    pub fn open() -> io::Result<PtyPort> {
        Pty::open()?.into_async()
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
