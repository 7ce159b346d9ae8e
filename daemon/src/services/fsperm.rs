//! The daemon's files and socket, never reachable by others: the socket's folder created 0700
//! (0750 for a socket group) or, when it exists, the daemon's own and writable by nobody else;
//! the socket bound in a private folder and moved into place with its mode already set, so it
//! is never reachable with a wider mode whatever the umask; a socket path taken over only
//! from a dead daemon; the store, its WAL and the logs 0600.

use std::fs::{DirBuilder, OpenOptions, Permissions};
use std::io;
use std::os::unix::fs::{DirBuilderExt, MetadataExt, OpenOptionsExt, PermissionsExt};
use std::path::Path;

/// Why the socket could not be set up; one sentence naming the path.
#[derive(Debug, thiserror::Error)]
pub enum SocketError {
    #[error("another daemon is already listening at {0}")]
    Busy(String),
    #[error("{path} exists and is not a socket ({what}): the daemon leaves it alone; remove it or choose another socket path")]
    NotASocket { path: String, what: String },
    #[error("the socket's folder {path} {why}; give the socket a folder of its own (e.g. $XDG_RUNTIME_DIR/machlink/machlink.sock)")]
    UnsafeFolder { path: String, why: String },
    #[error("cannot set up the socket at {path}: {source}")]
    Io {
        path: String,
        #[source]
        source: io::Error,
    },
}

fn io_err(path: &Path) -> impl Fn(io::Error) -> SocketError + '_ {
    move |source| SocketError::Io {
        path: path.display().to_string(),
        source,
    }
}

/// The mode of the socket's folder: 0700, or 0750 when a group may reach the socket.
pub fn folder_mode(group: Option<u32>) -> u32 {
    if group.is_some() {
        0o750
    } else {
        0o700
    }
}

/// Makes sure the socket's folder exists and nobody but the daemon's user can put anything
/// in it. A missing folder is created with mode 0700 (0750 with a socket group; the umask can
/// only narrow it), then given exactly that mode and group. An existing one must belong to
/// the daemon's user and be writable by nobody else (`/tmp` is refused).
pub fn socket_folder(dir: &Path, group: Option<u32>) -> Result<(), SocketError> {
    let mode = folder_mode(group);
    let err = io_err(dir);
    match std::fs::symlink_metadata(dir) {
        Err(e) if e.kind() == io::ErrorKind::NotFound => {
            DirBuilder::new()
                .recursive(true)
                .mode(mode)
                .create(dir)
                .map_err(&err)?;
            if let Some(g) = group {
                nix::unistd::chown(dir, None, Some(nix::unistd::Gid::from_raw(g)))
                    .map_err(|e| err(e.into()))?;
            }
            std::fs::set_permissions(dir, Permissions::from_mode(mode)).map_err(&err)?;
            Ok(())
        }
        Err(e) => Err(err(e)),
        Ok(m) => {
            let unsafe_folder = |why: String| SocketError::UnsafeFolder {
                path: dir.display().to_string(),
                why,
            };
            if !m.is_dir() {
                return Err(unsafe_folder("is not a folder".into()));
            }
            let me = nix::unistd::geteuid().as_raw();
            if m.uid() != me {
                return Err(unsafe_folder(format!(
                    "belongs to uid {}, not to the daemon's user (uid {me})",
                    m.uid()
                )));
            }
            let bits = m.mode() & 0o7777;
            if bits & 0o022 != 0 {
                return Err(unsafe_folder(format!(
                    "has mode {bits:04o}, writable by {}",
                    if bits & 0o002 != 0 {
                        "every user"
                    } else {
                        "its group"
                    }
                )));
            }
            Ok(())
        }
    }
}

/// Binds the socket at `path` (cleared by [`clear_socket_path`]) without a moment at a wider
/// mode: it is bound inside a fresh 0700 folder beside `path`, given its mode (0600, or 0660
/// for a socket group), then renamed into place.
pub fn bind_private(
    path: &Path,
    group: Option<u32>,
) -> Result<tokio::net::UnixListener, SocketError> {
    let err = io_err(path);
    let parent = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let nonce = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.subsec_nanos());
    let private = parent.join(format!(".ml{}.{nonce:x}", std::process::id()));
    DirBuilder::new()
        .mode(0o700)
        .create(&private)
        .map_err(&err)?;
    let result = (|| {
        let tmp = private.join("s");
        let l = tokio::net::UnixListener::bind(&tmp)?;
        set_socket_mode(&tmp, group).map_err(|e| match e {
            SocketError::Io { source, .. } => source,
            other => io::Error::other(other.to_string()),
        })?;
        std::fs::rename(&tmp, path)?;
        Ok(l)
    })();
    let _ = std::fs::remove_dir_all(&private);
    result.map_err(err)
}

/// Refuses a socket path that holds anything but a socket (a regular file, a folder, a
/// link), before the daemon touches any file: that path is left alone, and named.
pub fn check_socket_path(path: &Path) -> Result<(), SocketError> {
    match std::fs::symlink_metadata(path) {
        Err(e) if e.kind() == io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(io_err(path)(e)),
        Ok(m) => not_a_socket(path, &m),
    }
}

/// Clears the way for a socket at `path`: nothing there, or a socket no daemon answers on
/// (removed). A live daemon's socket, a regular file, a folder or a link are left alone.
pub async fn clear_socket_path(path: &Path) -> Result<(), SocketError> {
    let m = match std::fs::symlink_metadata(path) {
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(io_err(path)(e)),
        Ok(m) => m,
    };
    not_a_socket(path, &m)?;
    if tokio::net::UnixStream::connect(path).await.is_ok() {
        return Err(SocketError::Busy(path.display().to_string()));
    }
    std::fs::remove_file(path).map_err(io_err(path))
}

fn not_a_socket(path: &Path, m: &std::fs::Metadata) -> Result<(), SocketError> {
    use std::os::unix::fs::FileTypeExt;
    let t = m.file_type();
    if !t.is_socket() {
        let what = if t.is_file() {
            "a regular file"
        } else if t.is_dir() {
            "a folder"
        } else if t.is_symlink() {
            "a symbolic link"
        } else {
            "not a socket"
        };
        return Err(SocketError::NotASocket {
            path: path.display().to_string(),
            what: what.into(),
        });
    }
    Ok(())
}

/// The socket's own mode: 0600, or 0660 for a socket group (the folder is what keeps others
/// out while it is being created).
pub fn set_socket_mode(path: &Path, group: Option<u32>) -> Result<(), SocketError> {
    let err = io_err(path);
    if let Some(g) = group {
        nix::unistd::chown(path, None, Some(nix::unistd::Gid::from_raw(g)))
            .map_err(|e| err(e.into()))?;
    }
    let mode = if group.is_some() { 0o660 } else { 0o600 };
    std::fs::set_permissions(path, Permissions::from_mode(mode)).map_err(&err)
}

/// Makes the SQLite store private before SQLite opens it: the file is created 0600 (SQLite
/// gives its WAL and shared-memory files the database's mode), an existing one and its
/// `-wal` and `-shm` are narrowed to 0600.
pub fn private_store(path: &Path) -> io::Result<()> {
    match std::fs::symlink_metadata(path) {
        Err(e) if e.kind() == io::ErrorKind::NotFound => {
            OpenOptions::new()
                .write(true)
                .create_new(true)
                .mode(0o600)
                .open(path)?;
        }
        Err(e) => return Err(e),
        Ok(_) => {}
    }
    private_companions(path)
}

/// Narrows the store and its `-wal`, `-shm` and `-journal` files to 0600 where they exist.
pub fn private_companions(path: &Path) -> io::Result<()> {
    let mut names = vec![path.to_path_buf()];
    for suffix in ["-wal", "-shm", "-journal"] {
        let mut p = path.as_os_str().to_owned();
        p.push(suffix);
        names.push(p.into());
    }
    for p in names {
        match std::fs::metadata(&p) {
            Ok(m) if m.mode() & 0o077 != 0 => {
                std::fs::set_permissions(&p, Permissions::from_mode(0o600))?
            }
            _ => {}
        }
    }
    Ok(())
}

/// Opens a log for appending: created 0600, an existing one narrowed to 0600.
pub fn private_append(path: &Path) -> io::Result<std::fs::File> {
    let f = OpenOptions::new()
        .append(true)
        .create(true)
        .mode(0o600)
        .open(path)?;
    if f.metadata()?.mode() & 0o077 != 0 {
        f.set_permissions(Permissions::from_mode(0o600))?;
    }
    Ok(f)
}
