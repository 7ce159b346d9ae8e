#!/bin/sh
# Builds real GRBL 1.1h for Linux (grbl-sim) into DIR (default /tmp/grbl-sim), from
# GRBL_SRC and GRBL_SIM_SRC (git URLs or local clones; default GitHub). Prints the path of
# grbl_sim.exe; scripts/grbl-sim-check.py runs a program through it in check mode.
# docs/testing.md, "GRBL 1.1 itself", says why each step is there.
set -eu
DIR=${1:-/tmp/grbl-sim}
GRBL_SRC=${GRBL_SRC:-https://github.com/gnea/grbl}
GRBL_SIM_SRC=${GRBL_SIM_SRC:-https://github.com/grbl/grbl-sim}
rm -rf "$DIR"
mkdir -p "$DIR"
git clone -q "$GRBL_SRC" "$DIR/grbl"
git clone -q "$GRBL_SIM_SRC" "$DIR/grbl/grbl/grbl-sim"
cd "$DIR/grbl/grbl/grbl-sim"
# read stdin unbuffered: with getchar() the rest of a line sits in stdio's buffer, where
# the sim's select() does not see it, and each reply waits for the next line
sed -i 's|\t char_in = getchar();|\t if (read(STDIN_FILENO, \&char_in, 1) != 1) char_in = 0;|' platform_LINUX.c
# GCC 10+: the sim's globals need -fcommon
make main FLAGS="-g -O2 -fcommon" >/dev/null
echo "$DIR/grbl/grbl/grbl-sim/grbl_sim.exe"
