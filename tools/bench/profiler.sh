#!/usr/bin/env bash
# Scanning while printing, whole processes on this machine:
#
# 1. Throughput. A recording of the column printed with the profiler's full line (2,048
#    points a profile at 2 kHz, LAYERS layers) is made once with `asbuilt demo`; then RUNS
#    times a fresh agent, findings and the recorder on, takes it from `asbuilt replay` at full
#    speed. Each run's rate is the points over the time from the first pass's Begin to the
#    last report (the replay's own line), and the profiles a second at the recording's mean
#    points a profile; the median is printed, and whether any profile was refused.
# 2. Memory over a whole print. `asbuilt demo --sensor profiler` (the column's 60 layers) with
#    the agent's resident memory sampled every second; printed per tenth of the print.
#
#   tools/bench/profiler.sh                 # RUNS=3 LAYERS=10
set -euo pipefail
cd "$(dirname "$0")/../.."
RUNS=${RUNS:-3}
LAYERS=${LAYERS:-10}
OUT=${OUT:-out/profiler-bench}
ASBUILT=${ASBUILT:-$PWD/target/release/asbuilt}
if [ -z "${NO_BUILD:-}" ]; then
    cargo build --release -p asbuilt-tools -p asbuilt-agent 2> "$OUT.build.log" || {
        cat "$OUT.build.log" >&2
        exit 1
    }
fi
rm -rf "$OUT"
mkdir -p "$OUT"

echo "recording $LAYERS layers of the column at 2,048 points a profile, 2 kHz ..."
"$ASBUILT" demo --sensor profiler --part column --layers "$LAYERS" --profile-points 2048 \
    --out "$OUT/source" > "$OUT/source.log" 2>&1 || {
    tail -20 "$OUT/source.log" >&2
    exit 1
}
points_a_profile=$(grep -h 'profiles since start' "$OUT/source/agent.log" | tail -1 |
    grep -o '[0-9]* placed' | grep -o '[0-9]*')
total_points=$(grep -o 'overall *[0-9]*' "$OUT/source.log" | grep -o '[0-9]*$')
ppp=$(awk -v p="$total_points" -v n="$points_a_profile" 'BEGIN {printf "%.0f", p / n}')
echo "  $total_points points in $points_a_profile profiles: $ppp points a profile"

# The demo's agent configuration, on its own services and recording folder.
rates=()
for i in $(seq "$RUNS"); do
    dir="$OUT/run-$i"
    mkdir -p "$dir"
    cp "$OUT/source/design.stl" "$dir/"
    sed -e "s/^prefix = .*/prefix = \"asbuilt-profiler-bench-$$-$i\"/" \
        -e '/^\[viewer\]/,/^$/d' "$OUT/source/agent.toml" > "$dir/agent.toml"
    "$ASBUILT" agent --config "$dir/agent.toml" 2> "$dir/agent.log" &
    agent=$!
    "$ASBUILT" replay "$OUT/source/recording" --prefix "asbuilt-profiler-bench-$$-$i" \
        --wait 120 > "$dir/replay.log" 2>&1 || {
        kill "$agent" 2> /dev/null || true
        tail -20 "$dir/replay.log" >&2
        exit 1
    }
    kill -TERM "$agent"
    wait "$agent" || true
    rate=$(grep -o '[0-9.]* M points/s' "$dir/replay.log" | tail -1 | grep -o '^[0-9.]*')
    refused=$(grep -h 'profiles since start' "$dir/agent.log" | tail -1 |
        grep -o '[0-9]* refused' | head -1)
    rates+=("$rate")
    echo "  run $i: $rate M points/s, $(awk -v r="$rate" -v p="$ppp" \
        'BEGIN {printf "%.0f", r * 1e6 / p}') profiles/s; $refused"
done
median=$(printf '%s\n' "${rates[@]}" | sort -n | awk '{a[NR]=$1} END {print a[int((NR+1)/2)]}')
echo "throughput, median of $RUNS: $median M points/s with findings and the recorder on," \
    "$(awk -v r="$median" -v p="$ppp" 'BEGIN {printf "%.0f", r * 1e6 / p}') profiles/s of $ppp" \
    "points (the issue's 2,048 × 2,000 Hz is 4.1 M points/s)"

echo "memory over the demo's 60 layers ..."
"$ASBUILT" demo --sensor profiler --part column --out "$OUT/memory" > "$OUT/memory.log" 2>&1 &
demo=$!
agent=""
: > "$OUT/rss.txt"
while kill -0 "$demo" 2> /dev/null; do
    if [ -z "$agent" ]; then
        agent=$(pgrep -P "$demo" -f 'asbuilt agent' | head -1 || true)
    fi
    if [ -n "$agent" ] && [ -r "/proc/$agent/status" ]; then
        rss=$(awk '/^VmRSS/ {print $2}' "/proc/$agent/status" 2> /dev/null || true)
        passes=$(grep -c 'profiles since start' "$OUT/memory/agent.log" 2> /dev/null || true)
        [ -n "$rss" ] && echo "$passes $rss" >> "$OUT/rss.txt"
    fi
    sleep 1
done
wait "$demo" || { tail -20 "$OUT/memory.log" >&2; exit 1; }
# The first sample at or after each tenth of the passes, and the peak.
awk '{ d = int($1 / 6) * 6; if (!(d in at)) at[d] = $2 }
    END { for (p in at) printf "  %2d passes in: %.0f MB resident\n", p, at[p] / 1024 }' \
    "$OUT/rss.txt" | sort -n -k1
awk '$2 > peak { peak = $2 } END { printf "  peak: %.0f MB\n", peak / 1024 }' "$OUT/rss.txt"
