#!/usr/bin/env bash
# What judging by the standards costs `asbuilt report`: the demo's recording reported by this
# build and by another revision (BEFORE, default f4adf65: the last commit before issue 50's
# straightedge, uncertainty and decision rule), both with `--flatness din18202:6 --dimensions
# din18202`, alternated RUNS times, whole process, medians compared. The recording is made once
# by BEFORE's demo, which both builds read.
#
#   tools/bench/standards_cost.sh            # RUNS=5 BEFORE=f4adf65 OUT=out/standards-cost [OLD=…]
set -euo pipefail
cd "$(dirname "$0")/../.."
OUT=${OUT:-out/standards-cost}
RUNS=${RUNS:-5}
BEFORE=${BEFORE:-f4adf65}
ROOT=$PWD
mkdir -p "$OUT"
OUT=$(cd "$OUT" && pwd)
. tools/bench/timing.sh
cargo build --release --locked -p asbuilt-tools --bin asbuilt
# BEFORE in a worktree of its own, built to its own target directory (OLD: a binary already
# built from it).
if [ -z "${OLD:-}" ]; then
    if [ ! -d "$OUT/before" ]; then
        git worktree add --detach "$OUT/before" "$BEFORE" > /dev/null
    fi
    (cd "$OUT/before" && CARGO_TARGET_DIR="$OUT/before-target" cargo build --release --locked \
        -p asbuilt-tools --bin asbuilt -p asbuilt-agent --bin asbuilt-agent)
    OLD=$OUT/before-target/release/asbuilt
fi
NEW=$ROOT/target/release/asbuilt
if [ ! -d "$OUT/demo/recording" ]; then
    "$OLD" demo --out "$OUT/demo" > "$OUT/demo.log" 2>&1
fi
# One report into OUT/NAME: prints its wall and CPU seconds.
report() {
    local name=$1 bin=$2
    timed "$OUT/$name.log" "$bin" report "$OUT/demo/recording" --out "$OUT/$name" \
        --flatness din18202:6 --dimensions din18202
}
old_wall=(); old_cpu=(); new_wall=(); new_cpu=()
for i in $(seq "$RUNS"); do
    read -r w c < <(report before "$OLD"); old_wall+=("$w"); old_cpu+=("$c")
    read -r w c < <(report after "$NEW"); new_wall+=("$w"); new_cpu+=("$c")
done
cost() {
    awk -v what="$1" -v b="$(median "${@:2:$RUNS}")" -v a="$(median "${@:$((RUNS + 2))}")" \
        'BEGIN { printf "%s: median before %.3f s, after %.3f s: %+.1f %%\n", what, b, a, (a / b - 1) * 100 }'
}
cost "wall" "${old_wall[@]}" "${new_wall[@]}"
cost "CPU " "${old_cpu[@]}" "${new_cpu[@]}"
