//! The built `machlink` and `machlink-sim` binaries, for tests of this crate that run them as
//! an operator does. `env!("CARGO_BIN_EXE_…")` exists only inside the crate that owns the
//! binary, so this builds them (a no-op when they are fresh) into the target folder this test
//! binary runs from, with the cargo that runs the tests.
//!
//! The build is the one `cargo test --workspace` makes of the binaries: the `test` profile and
//! the whole workspace's features (tests/Cargo.toml says how they are kept equal). A plain
//! `cargo build` (the `dev` profile) would build the binaries and every dependency a second
//! time during the test run, and overwrite the binaries `cargo test` put in target/debug, so
//! the next run built them again.
#![allow(dead_code)]

use std::path::PathBuf;
use std::sync::OnceLock;

/// The folder holding `machlink` and `machlink-sim`, built once per test run.
pub fn bin_dir() -> PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        // target/<profile>/deps/it-<hash> -> target/<profile>
        let exe = std::env::current_exe().expect("the test binary's path");
        let profile = exe
            .parent()
            .and_then(|deps| deps.parent())
            .expect("the test binary lives in target/<profile>/deps")
            .to_path_buf();
        let target = profile.parent().expect("a target folder").to_path_buf();
        let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
        let mut build = std::process::Command::new(cargo);
        // What cargo sets for this test process only (the package's manifest and metadata)
        // is taken out again: the `cargo test` that built everything did not have it, and a
        // build script that watches one of them (ring's watches CARGO_MANIFEST_DIR) would
        // see it change and rebuild TLS, NATS and the daemon here, and once more in the
        // next `cargo test` (it cost this binary about 30 s in CI).
        for (key, _) in std::env::vars_os() {
            let key = key.to_string_lossy();
            if key.starts_with("CARGO_PKG_")
                || matches!(
                    &*key,
                    "CARGO_MANIFEST_DIR"
                        | "CARGO_MANIFEST_PATH"
                        | "CARGO_CRATE_NAME"
                        | "CARGO_PRIMARY_PACKAGE"
                        | "CARGO_TARGET_TMPDIR"
                )
            {
                build.env_remove(&*key);
            }
        }
        let status = build
            .args([
                "build",
                "--quiet",
                "--profile",
                "test",
                "--workspace",
                "--bins",
            ])
            .arg("--target-dir")
            .arg(&target)
            .status()
            .expect("cargo runs");
        assert!(
            status.success(),
            "cargo build of machlink and machlink-sim failed"
        );
        assert!(
            profile.join("machlink").is_file(),
            "no machlink binary in {}",
            profile.display()
        );
        profile
    })
    .clone()
}

/// The `machlink` binary.
pub fn machlink() -> PathBuf {
    bin_dir().join("machlink")
}
