#!/usr/bin/env bash
# The recording/replay comparison (`recording::a_recorded_job_replays_to_identical_reports`:
# the bunny job recorded by one agent, replayed into a fresh one, the reports equal bit for bit)
# run many times while two busy loops load the CPU, counting failures. A rare double report
# (11 reports for 10 stations) was once seen there; this is how to look for it. Not part of CI.
#
#   tools/bench/stress_replay.sh            # RUNS=500 OUT=out/stress-replay
set -euo pipefail
cd "$(dirname "$0")/../.."
RUNS=${RUNS:-500}
OUT=${OUT:-out/stress-replay}
TEST=${TEST:-recording::a_recorded_job_replays_to_identical_reports}
mkdir -p "$OUT"
BIN=$(cargo test --locked -p asbuilt-tests --test e2e --no-run --message-format=json 2> /dev/null |
    python3 -c 'import json,sys
for l in sys.stdin:
    m = json.loads(l)
    if m.get("reason") == "compiler-artifact" and m["target"]["name"] == "e2e" and m.get("executable"):
        print(m["executable"])' | tail -1)
[ -x "$BIN" ] || {
    echo "cannot find the e2e test binary" >&2
    exit 1
}
load() { while :; do :; done; }
load &
L1=$!
load &
L2=$!
trap 'kill $L1 $L2 2> /dev/null' EXIT
failed=0
started=$(date +%s)
for i in $(seq "$RUNS"); do
    if ! "$BIN" "$TEST" --exact > "$OUT/run.log" 2>&1; then
        failed=$((failed + 1))
        cp "$OUT/run.log" "$OUT/failed-$i.log"
        echo "run $i failed (kept as $OUT/failed-$i.log)"
    fi
    if [ $((i % 25)) -eq 0 ]; then
        echo "$i run(s), $failed failed, $(($(date +%s) - started)) s"
    fi
done
echo "$RUNS run(s) under load, $failed failed"
[ "$failed" -eq 0 ]
