#!/usr/bin/env bash
# What the flight recorder costs the agent at its full rate, over many runs: the throughput
# benchmark's recorder rounds (`-- --recorder ROUNDS`) RUNS times, and the medians of what each
# run printed. On a noisy two-core machine one run's cost moves by several per cent, so a
# change to the recorder wants a dozen runs, and its build before the change run in turn:
#
#   tools/bench/recorder_cost.sh                          # RUNS=9 ROUNDS=10, this build
#   BASE=/tmp/agent-before tools/bench/recorder_cost.sh   # this build and BASE, in turn
#
# BASE is an asbuilt-agent binary saved before the change (cp target/release/asbuilt-agent).
set -euo pipefail
cd "$(dirname "$0")/../.."
RUNS=${RUNS:-9}
ROUNDS=${ROUNDS:-10}
OUT=${OUT:-out/recorder-bench}
mkdir -p "$OUT"
rm -f "$OUT"/this-*.log "$OUT"/base-*.log
cargo bench -p asbuilt-agent --bench throughput --no-run 2> "$OUT/build.log" || {
    cat "$OUT/build.log" >&2
    exit 1
}
# The bench binary cargo just built (its name carries a hash).
bench=$(grep -o 'target/release/deps/throughput-[0-9a-f]*' "$OUT/build.log" | tail -1)
[ -x "$bench" ] || { echo "no throughput bench binary in $OUT/build.log" >&2; exit 1; }
builds=("this:$PWD/target/release/asbuilt-agent")
[ -n "${BASE:-}" ] && builds+=("base:$(realpath "$BASE")")
for i in $(seq "$RUNS"); do
    for b in "${builds[@]}"; do
        name=${b%%:*}
        ASBUILT_AGENT=${b#*:} "$bench" --recorder "$ROUNDS" > "$OUT/$name-$i.log" 2>&1 || {
            echo "run $i of $name failed: $OUT/$name-$i.log" >&2
            exit 1
        }
        echo "$name run $i: $(grep -o 'the recorder costs [^(]*' "$OUT/$name-$i.log" | head -1)"
    done
done
# Medians over the runs of one build: the ratio-of-medians cost, the round-by-round cost, the
# writer thread's CPU a point and the CPU the recorder adds to the agent's, each without and
# with Foxglove's channels.
median() { sort -n | awk '{a[NR]=$1} END {if (NR) print a[int((NR+1)/2)]; else print "?"}'; }
# The first (k = 1) or second (k = 0) percentage of the lines matching PATTERN in "${logs[@]}".
costs() { grep -h "$1" "${logs[@]}" | grep -o '[-0-9.]* %' | awk -v k="$2" 'NR % 2 == k {print $1}'; }
for b in "${builds[@]}"; do
    name=${b%%:*}
    logs=("$OUT/$name"-*.log)
    echo "$name (${#logs[@]} runs, medians):" \
        "cost $(costs 'points/s (medians' 1 | median) %," \
        "with Foxglove's channels $(costs 'points/s (medians' 0 | median) %;" \
        "round by round $(costs '^round by round' 1 | median) %," \
        "with Foxglove's channels $(costs '^round by round' 0 | median) %;" \
        "writer $(grep -h '^recordings: the writer' "${logs[@]}" | grep -o '[0-9.]* ns' | median) ns a point," \
        "with Foxglove's channels $(grep -h '^recordings-fox: the writer' "${logs[@]}" | grep -o '[0-9.]* ns' | median) ns;" \
        "CPU added $(costs '^the recorder adds' 1 | median) %," \
        "with Foxglove's channels $(costs '^the recorder adds' 0 | median) %"
done
