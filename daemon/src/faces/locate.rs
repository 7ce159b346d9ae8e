//! Where a client command finds the daemon's socket: `--socket`, then `MACHLINK_SOCKET`,
//! then the `socket` of the daemon's config (`--config FILE`, else `MACHLINK_CONFIG`, else
//! `./machlink.toml`, else `./cell.toml` (the name README's examples give it), else
//! `/etc/machlink/machlink.toml`, whichever exists first), then the
//! default (`$XDG_RUNTIME_DIR/machlink.sock`, else `/tmp/machlink-$USER/machlink.sock`).

use std::path::{Path, PathBuf};

/// The config file a service install puts in place (docs/install.md).
pub const SYSTEM_CONFIG: &str = "/etc/machlink/machlink.toml";

/// The config files a client looks for when none is named, in this order: the one `serve`
/// reads by default, the one README's examples start (`serve --config cell.toml`) in the
/// current folder, and the service's.
pub const CONFIG_SEARCH: [&str; 3] = ["machlink.toml", "cell.toml", SYSTEM_CONFIG];

/// Why the socket could not be found.
#[derive(Debug, thiserror::Error)]
pub enum LocateError {
    #[error("cannot read {path} to find the daemon's socket: {source}")]
    Read {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}: [daemon] socket: {message}")]
    Invalid { path: String, message: String },
}

/// The socket a client should use. `flag` is `--socket`, `config` is `--config`; `env`
/// reads an environment variable (the process's own in the binary).
pub fn socket(
    flag: Option<&Path>,
    config: Option<&Path>,
    env: impl Fn(&str) -> Option<String>,
) -> Result<PathBuf, LocateError> {
    if let Some(p) = flag {
        return Ok(p.to_path_buf());
    }
    if let Some(p) = env("MACHLINK_SOCKET").filter(|s| !s.is_empty()) {
        return Ok(PathBuf::from(p));
    }
    let file = match config {
        Some(c) => Some(c.to_path_buf()),
        None => env("MACHLINK_CONFIG")
            .filter(|s| !s.is_empty())
            .map(PathBuf::from)
            .or_else(|| {
                CONFIG_SEARCH
                    .iter()
                    .map(PathBuf::from)
                    .find(|p| p.is_file())
            }),
    };
    if let Some(file) = file {
        if let Some(s) = config_socket(&file)? {
            return Ok(s);
        }
    }
    Ok(crate::config::default_socket())
}

/// The `[daemon] socket` of a config file, relative paths taken from its folder; only that
/// key is read, so a client works with a config whose machines it cannot check.
pub fn config_socket(file: &Path) -> Result<Option<PathBuf>, LocateError> {
    let path = file.display().to_string();
    let text = std::fs::read_to_string(file).map_err(|source| LocateError::Read {
        path: path.clone(),
        source,
    })?;
    let table: toml::Table = toml::from_str(&text).map_err(|e| LocateError::Invalid {
        path: path.clone(),
        message: e.message().to_string(),
    })?;
    let Some(v) = table.get("daemon").and_then(|d| d.get("socket")) else {
        return Ok(None);
    };
    let s = v.as_str().ok_or_else(|| LocateError::Invalid {
        path,
        message: "must be a path in quotes".into(),
    })?;
    let p = PathBuf::from(s);
    Ok(Some(if p.is_relative() {
        file.parent().unwrap_or(Path::new(".")).join(p)
    } else {
        p
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flag_then_environment_then_config_then_default() {
        let dir = tempfile::tempdir().unwrap();
        let cfg = dir.path().join("cell.toml");
        std::fs::write(&cfg, "[daemon]\nsocket = \"run/ml.sock\"\n").unwrap();
        let none = |_: &str| None;
        let env_sock = |k: &str| (k == "MACHLINK_SOCKET").then(|| "/env.sock".to_string());
        let env_cfg = |k: &str| (k == "MACHLINK_CONFIG").then(|| cfg.display().to_string());
        let flag = Path::new("/flag.sock");
        assert_eq!(socket(Some(flag), Some(&cfg), env_sock).unwrap(), flag);
        assert_eq!(
            socket(None, Some(&cfg), env_sock).unwrap(),
            Path::new("/env.sock")
        );
        assert_eq!(
            socket(None, Some(&cfg), none).unwrap(),
            dir.path().join("run/ml.sock")
        );
        assert_eq!(
            socket(None, None, env_cfg).unwrap(),
            dir.path().join("run/ml.sock")
        );
        std::fs::write(&cfg, "[daemon]\nstore = \"x.db\"\n").unwrap();
        assert_eq!(
            socket(None, Some(&cfg), none).unwrap(),
            crate::config::default_socket()
        );
        let e = socket(None, Some(Path::new("/no/such.toml")), none).unwrap_err();
        assert!(
            e.to_string().starts_with("cannot read /no/such.toml"),
            "{e}"
        );
    }
}
