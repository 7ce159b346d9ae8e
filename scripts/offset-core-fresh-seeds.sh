#!/bin/sh
# The property tests of offset-core on N fresh seeds in a row (default 20), in release, at
# the plain case count (PROPTEST_CASES=256). Stops at the first failing seed and prints it
# (replay: PROPTEST_RNG_SEED=<seed> cargo test --release -p offset-core); proptest writes the
# failing draw to offset-core/tests/proptest-regressions/<module>.txt, which is then
# committed with the fix. Local only, not in CI: on two shared cores each seed takes minutes.
#
#   nice -n 19 scripts/offset-core-fresh-seeds.sh [N]
set -eu
n=${1:-20}
cd "$(dirname "$0")/.."
cargo test --release -p offset-core --no-run >/dev/null 2>&1 || cargo test --release -p offset-core --no-run
i=0
while [ "$i" -lt "$n" ]; do
    seed=$(od -An -N4 -tu4 /dev/urandom | tr -d ' ')
    i=$((i + 1))
    echo "seed $i of $n: PROPTEST_RNG_SEED=$seed PROPTEST_CASES=256"
    if ! PROPTEST_RNG_SEED=$seed PROPTEST_CASES=256 cargo test --release -q -p offset-core >"${TMPDIR:-/tmp}/offset-core-seed-$seed.log" 2>&1; then
        echo "FAILED on seed $seed (after $((i - 1)) passing in a row); log: ${TMPDIR:-/tmp}/offset-core-seed-$seed.log"
        grep -E "^test .* FAILED|minimal failing input|panicked" "${TMPDIR:-/tmp}/offset-core-seed-$seed.log" | head -20
        exit 1
    fi
    echo "  passed"
    rm -f "${TMPDIR:-/tmp}/offset-core-seed-$seed.log"
done
echo "$n fresh seeds in a row passed"
