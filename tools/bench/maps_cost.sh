#!/usr/bin/env bash
# What report.html's deviation maps cost `inspect`: the same job with and without `--no-maps`,
# alternated RUNS times, whole process, medians compared. The job is the worst case for the
# maps: 2 M noisy bunny points in no spatial order (c2m_bench_inputs' bunny_shuffled.ply), so
# every mark lands on a pixel the last one did not touch.
#
#   tools/bench/maps_cost.sh            # RUNS=9 OUT=out/maps-bench
set -euo pipefail
cd "$(dirname "$0")/../.."
OUT=${OUT:-out/maps-bench}
RUNS=${RUNS:-9}
. tools/bench/inputs.sh
. tools/bench/timing.sh
# One inspect into OUT/NAME, its output into OUT/NAME.log: prints its wall and CPU seconds.
inspect() {
    local name=$1
    timed "$OUT/$name.log" \
        target/release/asbuilt inspect --design ../shared/data/stanford-bunny/bun_zipper.ply \
        --units m --scan "$OUT/bunny_shuffled.ply" --translation 0,0,0 --rotation-xyzw 0,0,0,1 \
        --out "$OUT/$name" "${@:2}"
}
with_wall=(); with_cpu=(); without_wall=(); without_cpu=()
for i in $(seq "$RUNS"); do
    read -r w c < <(inspect maps); with_wall+=("$w"); with_cpu+=("$c")
    read -r w c < <(inspect no-maps --no-maps); without_wall+=("$w"); without_cpu+=("$c")
done
cost() {
    awk -v what="$1" -v m="$(median "${@:2:$RUNS}")" -v n="$(median "${@:$((RUNS + 2))}")" \
        'BEGIN { printf "%s: median with maps %.3f s, without %.3f s: the maps cost %.1f %%\n", what, m, n, (m / n - 1) * 100 }'
}
cost "wall" "${with_wall[@]}" "${without_wall[@]}"
cost "CPU " "${with_cpu[@]}" "${without_cpu[@]}"
