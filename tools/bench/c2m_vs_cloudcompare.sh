#!/usr/bin/env bash
# C2M side by side with CloudCompare's command line (Debian's `cloudcompare`), whole process,
# the same files for both: wall time and peak RSS, median of RUNS runs taken in alternation.
# Not part of CI: it installs CloudCompare if missing.
#
#   tools/bench/c2m_vs_cloudcompare.sh            # RUNS=3 OUT=out/c2m-bench
#
# Jobs: (a) the 69,451-triangle Stanford bunny with 2 M noisy points in scan order and shuffled,
# (b) a generated 1,004,000-triangle twisted column with 1 M noisy points. Maximum distance 5 mm.
set -euo pipefail
cd "$(dirname "$0")/../.."
RUNS=${RUNS:-3}
OUT=${OUT:-out/c2m-bench}
BUNNY=../shared/data/stanford-bunny/bun_zipper.ply
if ! command -v CloudCompare >/dev/null; then
    apt-get update >/dev/null && apt-get install -y cloudcompare >/dev/null
fi
if [ ! -x /usr/bin/time ]; then
    apt-get install -y time >/dev/null
fi
. tools/bench/inputs.sh
export QT_QPA_PLATFORM=offscreen

# run NAME CMD... : appends "seconds kilobytes" to $OUT/NAME.times
run() {
    local name=$1
    shift
    /usr/bin/time -f "%e %M" -o "$OUT/$name.last" "$@" >"$OUT/$name.log" 2>&1 ||
        { echo "$name failed, see $OUT/$name.log" >&2; exit 1; }
    cat "$OUT/$name.last" >>"$OUT/$name.times"
}

median() { sort -n | awk '{a[NR]=$1} END {print a[int((NR+1)/2)]}'; }

jobs=("bunny_scan $BUNNY bunny_scan.ply" "bunny_shuffled $BUNNY bunny_shuffled.ply"
      "column $OUT/column.stl column_scan.ply")
for j in "${jobs[@]}"; do
    set -- $j
    rm -f "$OUT/$1.asbuilt.times" "$OUT/$1.cloudcompare.times"
done
for r in $(seq "$RUNS"); do
    for j in "${jobs[@]}"; do
        set -- $j
        name=$1 mesh=$2 points=$OUT/$3
        run "$name.asbuilt" target/release/asbuilt inspect --design "$mesh" --units m \
            --scan "$points" --translation 0,0,0 --rotation-xyzw 0,0,0,1 \
            --tolerance 0.0005 --max-distance 0.005 --out "$OUT/$name-asbuilt"
        run "$name.cloudcompare" CloudCompare -SILENT -NO_TIMESTAMP -C_EXPORT_FMT PLY \
            -O "$points" -O "$mesh" -C2M_DIST -MAX_DIST 0.005 -SAVE_CLOUDS
    done
done

printf '\n%-16s %14s %14s %12s %14s %14s\n' job "asbuilt s" "CloudCompare s" "speed-up" \
    "asbuilt MB" "CloudCompare MB"
for j in "${jobs[@]}"; do
    set -- $j
    a_s=$(cut -d' ' -f1 "$OUT/$1.asbuilt.times" | median)
    c_s=$(cut -d' ' -f1 "$OUT/$1.cloudcompare.times" | median)
    a_m=$(cut -d' ' -f2 "$OUT/$1.asbuilt.times" | median)
    c_m=$(cut -d' ' -f2 "$OUT/$1.cloudcompare.times" | median)
    awk -v n="$1" -v as="$a_s" -v cs="$c_s" -v am="$a_m" -v cm="$c_m" 'BEGIN {
        printf "%-16s %14.2f %14.2f %11.2fx %14.0f %14.0f\n", n, as, cs, cs / as, am / 1024, cm / 1024 }'
done
echo "(median of $RUNS runs each; every run in $OUT/*.times; index figures in $OUT/*.asbuilt.log)"
