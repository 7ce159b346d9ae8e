#!/usr/bin/env python3
"""Runs a G-code program through real GRBL 1.1 (grbl-sim's grbl_sim.exe) in check mode ($C).

Usage: grbl-sim-check.py GRBL_SIM_EXE PROGRAM.nc

GRBL parses and checks every line (words, modal groups, arcs) without moving. Lines are sent
one at a time, each after the last one's reply; every `error:N` is printed with its line
number. A line answered `error:1` or not at all is sent once more (bytes get lost on the
terminal on a loaded machine; the programs are absolute, G90, so a line seen twice moves to
the same place); the count of such lines is printed. Exit status: 0 when every line is `ok`, 1 on any error, 2 when the simulator does not
answer. How to build grbl_sim.exe: docs/testing.md, "GRBL 1.1 itself".
"""
import os
import pty
import select
import subprocess
import sys
import time
import tty


def main():
    if len(sys.argv) != 3:
        print(__doc__.strip().splitlines()[2], file=sys.stderr)
        return 2
    exe, program = sys.argv[1], sys.argv[2]
    master, slave = pty.openpty()
    tty.setraw(slave)
    sim = subprocess.Popen(
        # -c: no comment character before each reply
        [exe, "-c", "-b", os.devnull, "-s", os.devnull],
        # a terminal on both sides: on a pipe the sim's stdout is block-buffered and its
        # replies would wait for the buffer to fill
        stdin=slave,
        stdout=slave,
        stderr=subprocess.DEVNULL,
    )
    os.close(slave)
    buf = b""

    def reply(timeout=10.0):
        """The next line GRBL writes (None after `timeout` seconds of silence)."""
        nonlocal buf
        end = time.time() + timeout
        while b"\n" not in buf:
            left = end - time.time()
            if left <= 0:
                return None
            r, _, _ = select.select([master], [], [], left)
            if r:
                try:
                    chunk = os.read(master, 4096)
                except OSError:
                    return None
                if not chunk:
                    return None
                buf += chunk
        line, buf = buf.split(b"\n", 1)
        line = line.decode(errors="replace").strip()
        return line if line else reply(max(end - time.time(), 0.1))

    def send(line):
        os.write(master, line.encode() + b"\n")
        while True:
            r = reply()
            if r is None:
                return None
            if r == "ok" or r.startswith("error:"):
                return r

    try:
        while True:
            r = reply()
            if r is None:
                print("grbl-sim never printed its banner", file=sys.stderr)
                return 2
            if r.startswith("Grbl"):
                break
        if send("$C") != "ok":
            print("grbl-sim refused check mode ($C)", file=sys.stderr)
            return 2
        errors = 0
        checked = 0
        resent = 0
        with open(program) as f:
            for n, line in enumerate(f, 1):
                line = line.strip()
                if not line:
                    continue
                r = send(line)
                # error:1 (a word without its letter) on a line of whole words, or no
                # reply: bytes lost on the terminal (seen on a loaded machine, a different
                # line each run). GRBL refused the line or never had it whole, so it is sent
                # once more; an error that comes back is counted.
                if r is None or r == "error:1":
                    resent += 1
                    r = send(line)
                if r is None:
                    print(f"line {n}: no reply to {line!r}", file=sys.stderr)
                    return 2
                checked += 1
                if r != "ok":
                    errors += 1
                    print(f"line {n}: {r}: {line}")
        print(
            f"{checked} lines checked in check mode, {errors} errors"
            + (f" ({resent} lines sent twice: lost on the terminal)" if resent else "")
        )
        return 1 if errors else 0
    finally:
        sim.kill()
        sim.wait()


if __name__ == "__main__":
    sys.exit(main())
