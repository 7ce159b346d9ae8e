#!/usr/bin/env python3
"""The slowest tests of `cargo test --workspace`, one by one (docs/testing.md, "Time of the
test command").

Usage: scripts/test-times.py [--top N] [FILTER]

`cargo test` on stable Rust reports each binary's time, not each test's. This builds the
test binaries as `cargo test --workspace` does (`cargo test --workspace --no-run`, with the
environment you give it: set CARGO_INCREMENTAL=0 as .ci/run does, or the build differs from
CI's), then runs every test binary from its package's folder, as cargo does, one after
another, with libtest's per-test timing (`-Z unstable-options --report-time --format json`,
allowed on stable by RUSTC_BOOTSTRAP=1 for the test binaries only), and prints the slowest
N tests (default 10) with their binaries, each binary's wall time, and the count of tests.

RUSTC_BOOTSTRAP must not reach the cargo that the end-to-end tests run to find the built
binaries (tests/tests/it/common/bin.rs): cargo fingerprints it, and that build would then
rebuild everything. So CARGO points at a small wrapper that drops it.

The test threads are cargo's (.cargo/config.toml sets RUST_TEST_THREADS=4); the property
tests take PROPTEST_RNG_SEED and PROPTEST_CASES from the environment as in .ci/run.
FILTER, if given, is passed to every binary (a test name substring).
"""
import json
import os
import stat
import subprocess
import sys
import tempfile
import time


def test_binaries():
    """(executable, package folder, name) of every test binary `cargo test --workspace` runs."""
    out = subprocess.run(
        ["cargo", "test", "--workspace", "--no-run", "--message-format=json"],
        check=True,
        stdout=subprocess.PIPE,
    ).stdout
    bins = []
    for line in out.splitlines():
        msg = json.loads(line)
        if msg.get("reason") != "compiler-artifact" or not msg.get("executable"):
            continue
        if not msg.get("profile", {}).get("test"):
            continue
        pkg_dir = os.path.dirname(msg["manifest_path"])
        t = msg["target"]
        bins.append((msg["executable"], pkg_dir, f"{os.path.basename(pkg_dir)} {t['kind'][0]} {t['name']}"))
    return bins


def main():
    args = sys.argv[1:]
    top = 10
    if args[:1] == ["--top"]:
        top = int(args[1])
        args = args[2:]
    filt = args[:1]
    bins = test_binaries()
    tmp = tempfile.mkdtemp(prefix="test-times")
    wrapper = os.path.join(tmp, "cargo")
    real_cargo = os.environ.get("CARGO", "cargo")
    with open(wrapper, "w") as f:
        f.write(f"#!/bin/sh\nunset RUSTC_BOOTSTRAP\nexec {real_cargo} \"$@\"\n")
    os.chmod(wrapper, os.stat(wrapper).st_mode | stat.S_IEXEC)
    env = dict(os.environ, RUSTC_BOOTSTRAP="1", CARGO=wrapper)
    env.setdefault("RUST_TEST_THREADS", "4")
    times = []
    failed = []
    for exe, pkg_dir, name in bins:
        t0 = time.time()
        p = subprocess.run(
            [exe, *filt, "-Z", "unstable-options", "--format", "json", "--report-time"],
            cwd=pkg_dir,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
        )
        wall = time.time() - t0
        n = 0
        for line in p.stdout.splitlines():
            try:
                e = json.loads(line)
            except ValueError:
                continue
            if e.get("type") == "test" and e.get("event") in ("ok", "failed"):
                n += 1
                times.append((e.get("exec_time", 0.0), e["name"], name))
                if e["event"] == "failed":
                    failed.append(f"{name}: {e['name']}")
        print(f"{wall:7.1f} s  {n:4d} tests  {name}", flush=True)
    times.sort(reverse=True)
    print(f"\nthe {top} slowest tests (seconds, binary, test) of {len(times)} run:")
    for t, test, name in times[:top]:
        print(f"{t:7.1f}  {name}  {test}")
    if failed:
        print("\nfailed:\n" + "\n".join(failed))
        sys.exit(1)


if __name__ == "__main__":
    main()
