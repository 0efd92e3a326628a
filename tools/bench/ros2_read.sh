#!/usr/bin/env bash
# How fast and in how much memory a ROS 2 bag is read, whole process: `asbuilt convert --ros2`
# of a bag written by the independent `rosbags` writer (tools/bench/ros2_bag.py: clouds of
# 65,536 points at 10 Hz, /tf at 50 Hz) into a binary PLY, RUNS times; the median wall time,
# points per second and the largest resident memory.
#
#   tools/bench/ros2_read.sh            # SIZE_MB=1024 RUNS=3 STORAGE=mcap
set -euo pipefail
cd "$(dirname "$0")/../.."
: "${SIZE_MB:=1024}" "${RUNS:=3}" "${STORAGE:=mcap}" "${OUT:=out/ros2-read}"
venv=target/bench-venv
[ -x "$venv/bin/python" ] || python3 -m venv "$venv"
"$venv/bin/pip" install --quiet --disable-pip-version-check rosbags numpy
cargo build --release --locked -p asbuilt-tools --bin asbuilt
mkdir -p "$OUT"
bag="$OUT/bag-$SIZE_MB-$STORAGE"
if [ ! -d "$bag" ]; then
    "$venv/bin/python" tools/bench/ros2_bag.py "$bag" "$SIZE_MB" 65536 "$STORAGE"
fi
du -sh "$bag"
points=$(( $(du -sb "$bag" | cut -f1) / 16 / 65536 * 65536 ))
for run in $(seq "$RUNS"); do
    /usr/bin/time -f "%e %M" -o "$OUT/time-$run" \
        target/release/asbuilt convert --ros2 "$bag" --out "$OUT/out.ply" > "$OUT/log-$run" 2>&1
    rm -f "$OUT/out.ply"
    read -r secs kib < "$OUT/time-$run"
    n=$(grep -o '[0-9]* of [0-9]* points' "$OUT/log-$run" | cut -d' ' -f1 || echo "$points")
    echo "run $run: $secs s, $(awk -v n="$n" -v s="$secs" 'BEGIN { printf "%.1f", n / s / 1e6 }') M points/s, max RSS $((kib / 1024)) MB ($n points)"
done | tee "$OUT/runs.txt"
sort -t: -k2 -n "$OUT/runs.txt" | awk -v r="$RUNS" 'NR == int((r + 1) / 2) { print "median " $0 }'
