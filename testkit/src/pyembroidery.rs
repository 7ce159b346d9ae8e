//! The peer reader of the sewing tests: what `pyembroidery` reads from a DST or JEF file.

/// What pyembroidery reads from `path`: (x, y, command) per record, in its units (0.1 mm,
/// y down; the command's low byte, pyembroidery's EmbConstant). Fails (never skips) when
/// python3 or pyembroidery is missing, saying how to install them.
pub fn pyembroidery_read(path: &std::path::Path) -> Vec<(f64, f64, u32)> {
    let script = "import sys, json, pyembroidery\n\
        p = pyembroidery.read(sys.argv[1])\n\
        print(json.dumps([[x, y, int(c) & 0xFF] for x, y, c in p.stitches]))";
    let out = std::process::Command::new("python3")
        .arg("-c")
        .arg(script)
        .arg(path)
        .output()
        .unwrap_or_else(|e| panic!("python3 is needed for this test and does not run: {e}"));
    assert!(
        out.status.success(),
        "python3 with pyembroidery is needed for this test (run .ci/run, or `python3 -m pip \
         install -r .ci/requirements.txt`); reading {} failed: {}",
        path.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("pyembroidery's records as JSON")
}
