#!/usr/bin/env bash
# Many crash soaks in a row (tools/bench/crash_soak.sh): seeds 1..N, KILLS kills each, the loop
# closed on the even seeds, and a table of what each gave. Fails when any soak fails. A soak's
# folder (its recordings, about 3.4 GB) is removed when it passes, unless KEEP=1.
#
#   tools/bench/crash_soaks.sh                # N=20 KILLS=10 OUT=out/crash-soaks
set -uo pipefail
cd "$(dirname "$0")/../.."
: "${N:=20}" "${KILLS:=10}" "${OUT:=out/crash-soaks}"
mkdir -p "$OUT"
if [ -z "${BIN:-}" ]; then
    cargo build --release --locked -p asbuilt-tools --bin asbuilt -p asbuilt-agent --bin asbuilt-agent || exit 1
    BIN=target/release
fi
failed=0
printf '| seed | loop | result | kills | cell | restart to serving (median / max s) | findings equal |\n'
printf '| --- | --- | --- | --- | --- | --- | --- |\n'
for seed in $(seq "$N"); do
    loop=open
    closed=()
    if [ $((seed % 2)) -eq 0 ]; then
        loop=closed
        closed=(CLOSED_LOOP=1)
    fi
    log="$OUT/soak-$seed.log"
    env "${closed[@]}" BIN="$BIN" SEED="$seed" KILLS="$KILLS" OUT="$OUT/soak-$seed" \
        tools/bench/crash_soak.sh > "$log" 2>&1
    rc=$?
    [ "$rc" -eq 0 ] || failed=$((failed + 1))
    kills=$(grep -o '^kills: [0-9]*' "$log" | grep -o '[0-9]*$')
    cell=$(grep -o 'the cell exited with [0-9]*' "$log" | grep -o '[0-9]*$')
    restart=$(grep -o 'restart to serving: median [0-9.]* s, max [0-9.]* s' "$log" |
        sed 's/restart to serving: median \([0-9.]*\) s, max \([0-9.]*\) s/\1 \/ \2/')
    equal=$(grep -o 'equal to the reference: [A-Za-z]*' "$log" | grep -o '[A-Za-z]*$')
    result=$([ "$rc" -eq 0 ] && echo PASS || echo "FAIL: $(grep -m1 '^FAIL' "$log" | cut -c7-90)")
    printf '| %s | %s | %s | %s | %s | %s | %s |\n' "$seed" "$loop" "$result" "${kills:-?}" \
        "${cell:-?}" "${restart:-?}" "${equal:-?}"
    if [ "$rc" -eq 0 ] && [ "${KEEP:-0}" != 1 ]; then
        rm -rf "$OUT/soak-$seed"
    fi
done
echo "$failed of $N soak(s) failed"
[ "$failed" -eq 0 ]
