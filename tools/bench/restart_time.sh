#!/usr/bin/env bash
# Restart time: the agent killed with SIGKILL in the last scan layer of a job (while that
# layer's third station sends) and started again at once; how long from process start to
# serving, and what it recovered (files, reports, the stations of the current scan layer
# replayed and their points, the scan layer's findings state). Then the job goes on to its end.
# Not part of CI.
#
#   tools/bench/restart_time.sh                      # the demo wall, OUT=out/restart-wall
#   PART=column tools/bench/restart_time.sh          # the 1,004,000-triangle column
#   BIN=target/debug ASBUILT=e2e-asbuilt AGENT=e2e-asbuilt-agent tools/bench/restart_time.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
PART=${PART:-wall}
OUT=${OUT:-out/restart-$PART}
if [ -z "${BIN:-}" ]; then
    cargo build --release --locked -p asbuilt-tools --bin asbuilt -p asbuilt-agent --bin asbuilt-agent \
        --example c2m_bench_inputs
    BIN=target/release
fi
BIN=$(cd "$BIN" && pwd)
ASBUILT=$BIN/${ASBUILT:-asbuilt}
AGENT=$BIN/${AGENT:-asbuilt-agent}
case "$PART" in
wall)
    JOB=(--part wall)
    LAYERS=()
    LAST=48
    ;;
column)
    INPUTS=${INPUTS:-out/c2m-bench}
    [ -f "$INPUTS/column.stl" ] || "$BIN/examples/c2m_bench_inputs" "$INPUTS"
    JOB=(--part "$(cd "$INPUTS" && pwd)/column.stl" --units m --layer-height 0.02)
    LAYERS=(--scan-after 10,30,50)
    LAST=50
    ;;
*)
    echo "PART=wall or PART=column" >&2
    exit 2
    ;;
esac
rm -rf "$OUT"
mkdir -p "$OUT"
# The demo's agent configuration and design, from a demo of a single scan layer.
"$ASBUILT" demo "${JOB[@]}" --scan-after 1 --stations 1 --no-defects --out "$OUT/setup" > "$OUT/setup.log" 2>&1
PREFIX=asbuilt-restart-$$
sed -e "s/^prefix = .*/prefix = \"$PREFIX\"/" -e '/^\[viewer\]/,/^rrd/d' \
    -e "s|^path = .*|path = \"$(cd "$OUT/setup" && pwd)/design.stl\"|" \
    "$OUT/setup/agent.toml" > "$OUT/agent.toml"
cd "$OUT"
"$AGENT" --config agent.toml > agent-0.log 2>&1 &
AGENT_PID=$!
for _ in $(seq 1200); do grep -q "serving " agent-0.log && break; sleep 0.1; done
"$ASBUILT" sim --prefix "$PREFIX" --findings --wait 120 "${JOB[@]}" "${LAYERS[@]}" > sim.log 2>&1 &
SIM=$!
# Kill while the last scan layer's third station sends: its second is reported.
STATION=$(printf "L%03d-S2" "$LAST")
until grep -q "$STATION .* Complete" sim.log; do
    kill -0 "$SIM" 2> /dev/null || {
        tail sim.log
        exit 1
    }
    sleep 0.05
done
sleep 0.3
kill -9 "$AGENT_PID"
wait "$AGENT_PID" 2> /dev/null || true
"$AGENT" --config agent.toml > agent-1.log 2>&1 &
AGENT_PID=$!
SIM_EXIT=0
wait "$SIM" || SIM_EXIT=$?
kill -TERM "$AGENT_PID"
wait "$AGENT_PID" 2> /dev/null || true
echo "the cell exited with $SIM_EXIT"
grep "interruption(s)" sim.log || true
grep -h "design .* triangles\|resume:\|serving \|scan layer at" agent-1.log | cut -c25- | head -12
du -ch recording/*.mcap | tail -1 | sed 's/^/recording files: /'
