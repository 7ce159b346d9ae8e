#!/usr/bin/env python3
"""Stage times of `machlink plan` of a pocket (docs/BENCHMARKS.md, issue 25).

Usage: scripts/plan-timings.py [--runs N] BINARY [BINARY ...]

Writes issue 13's gear (r = 60 + 4 sin 24t + 3 sin 5t, 10,000 vertices, 3 round islands
of radius 8 on a circle of radius 28) as geometry JSON, then runs, in rounds that
interleave the binaries (round k runs each binary once, the order rotating), `BINARY plan
gear.json --op pocket --tool-diameter 3 --stepover 40% --depth 1 --timings -o OUT` and the
anchor `BINARY --version` (the process start-up floor). Prints, per binary, the best and
the median of each stage `--timings` reports, the time outside `plan` and `fit` and, for
builds that time the JSON import's arc fitting (`import fit`), outside all three (both
computed here from the stages and the total, whatever the build calls them), the whole
process's wall time measured from outside (each run writes a new file: the previous run's
output is removed before it, outside the timing, since on ext4 truncating it waits for its
write-back), and the 1-minute load average before and after; and whether the binaries wrote
the same program text.
"""
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time


def gear_json(path):
    n = 10_000
    pts = []
    for i in range(n):
        a = 2 * math.pi * i / n
        r = 60 + 4 * math.sin(24 * a) + 3 * math.sin(5 * a)
        pts.append("[%.17g,%.17g]" % (r * math.cos(a), r * math.sin(a)))
    paths = ['{"closed": true, "vertices": [%s]}' % ",".join(pts)]
    for k in range(3):
        a = 2 * math.pi * k / 3
        cx, cy = 28 * math.cos(a), 28 * math.sin(a)
        paths.append(
            '{"closed": true, "vertices": [[%.17g,%.17g,1],[%.17g,%.17g,1]]}'
            % (cx - 8, cy, cx + 8, cy)
        )
    with open(path, "w") as f:
        f.write('{"units": "mm", "paths": [%s]}\n' % ",".join(paths))


def load():
    with open("/proc/loadavg") as f:
        return f.read().split()[0]


def parse_timings(stderr):
    for line in stderr.splitlines():
        line = line.strip()
        if line.startswith("timings (ms):"):
            out = {}
            for part in line[len("timings (ms):"):].split(","):
                words = part.split()
                if len(words) >= 2:
                    name = " ".join(words[:-1])
                    # the builds' own "outside …" figures differ in what they leave out
                    # (the first called plan and fit "the geometry"; later ones count the
                    # JSON import's arc fitting there too): both are derived below
                    if not name.startswith("outside"):
                        out[name] = float(words[-1])
            total = out.get("total", 0.0)
            plan_fit = out.get("plan", 0.0) + out.get("fit", 0.0)
            out["outside plan and fit"] = total - plan_fit
            if "import fit" in out:
                out["outside the geometry (all but import fit, plan, fit)"] = (
                    total - plan_fit - out["import fit"])
            return out
    raise SystemExit("no timings line in the output of plan:\n" + stderr)


def main():
    args = sys.argv[1:]
    runs = 15
    if args[:1] == ["--runs"]:
        runs, args = int(args[1]), args[2:]
    if not args:
        raise SystemExit(__doc__)
    bins = [os.path.abspath(b) for b in args]
    tmp = tempfile.mkdtemp(prefix="plan-timings-")
    shape = os.path.join(tmp, "gear.json")
    gear_json(shape)
    samples = {b: [] for b in bins}
    anchor = {b: [] for b in bins}
    outputs = {}
    print(f"load average (1 min) at the start: {load()}")
    for k in range(runs):
        for j in range(len(bins)):
            b = bins[(j + k) % len(bins)]
            out = os.path.join(tmp, f"out{bins.index(b)}.nc")
            t = time.perf_counter()
            subprocess.run([b, "--version"], check=True, capture_output=True)
            anchor[b].append((time.perf_counter() - t) * 1e3)
            # a new file each run: on ext4, truncating the previous run's program waits for
            # its write-back to the disk (about 4 ms here), which is the disk's time, not
            # the planner's
            if os.path.exists(out):
                os.remove(out)
            cmd = [b, "plan", shape, "--op", "pocket", "--tool-diameter", "3",
                   "--stepover", "40%", "--depth", "1", "--timings", "-o", out]
            t = time.perf_counter()
            p = subprocess.run(cmd, capture_output=True, text=True)
            wall = (time.perf_counter() - t) * 1e3
            if p.returncode != 0:
                raise SystemExit(f"{b} plan failed: {p.stderr}")
            st = parse_timings(p.stderr)
            st["process (outside view)"] = wall
            samples[b].append(st)
            with open(out, "rb") as f:
                outputs[b] = f.read()
    print(f"load average (1 min) at the end: {load()}")
    print()
    print(f"`machlink plan` of the 10,000-vertex gear with 3 islands, {runs} rounds, "
          "ms, best / median")
    print()
    print("| stage | " + " | ".join(bins) + " |")
    print("|---|" + "---:|" * len(bins))
    stages = list(samples[bins[0]][0].keys())
    for b in bins[1:]:
        for s in samples[b][0]:
            if s not in stages:
                stages.append(s)
    for s in stages:
        cells = []
        for b in bins:
            v = [x[s] for x in samples[b] if s in x]
            cells.append(f"{min(v):.2f} / {statistics.median(v):.2f}" if v else "–")
        print(f"| {s} | " + " | ".join(cells) + " |")
    cells = [f"{min(anchor[b]):.2f} / {statistics.median(anchor[b]):.2f}" for b in bins]
    print("| anchor: `--version` (process start-up) | " + " | ".join(cells) + " |")
    same = len(set(outputs.values())) == 1
    print()
    print("the binaries wrote the same program: " + ("yes" if same else "NO"))


if __name__ == "__main__":
    main()
