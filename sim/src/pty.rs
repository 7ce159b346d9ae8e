//! Pseudo-terminals for simulated devices: a raw pty pair whose slave path a client opens.

use nix::fcntl::{fcntl, FcntlArg, OFlag};
use nix::poll::{poll, PollFd, PollFlags, PollTimeout};
use nix::sys::termios::{cfmakeraw, tcgetattr, tcsetattr, SetArg};
use std::io;
use std::os::fd::{AsFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::time::Duration;

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
