#!/usr/bin/env bash
# Crash soak: the demo job (the wall with its four defects, findings on, 24 stations) runs
# while the agent is killed with SIGKILL at seeded random moments and started again within a
# second each time, with the same configuration. It holds when the cell finishes the job naming
# each interruption, every station ends Complete exactly once, and `asbuilt report` over the
# job's files gives the stations and findings of the same job run without kills (the demo).
# Also prints each restart's time from process start to serving, and what it recovered. It
# fails on fewer kills than asked, a panic in any agent's log, and any warning of the report
# that what the agents told the cell live differs from what is drawn again from the recording.
# Not part of CI (the e2e test `crash` runs a shorter job the same way).
#
#   tools/bench/crash_soak.sh                 # SEED=1 KILLS=12 OUT=out/crash-soak
#   BIN=target/debug ASBUILT=e2e-asbuilt AGENT=e2e-asbuilt-agent tools/bench/crash_soak.sh
#   CLOSED_LOOP=1 tools/bench/crash_soak.sh   # the printer applies the agent's advice: what is
#                                             # printed depends on advice taken up after each kill
set -euo pipefail
cd "$(dirname "$0")/../.."
OUT=${OUT:-out/crash-soak}
SEED=${SEED:-1}
KILLS=${KILLS:-12}
LOOP=()
[ -n "${CLOSED_LOOP:-}" ] && LOOP=(--closed-loop)
if [ -z "${BIN:-}" ]; then
    cargo build --release --locked -p asbuilt-tools --bin asbuilt -p asbuilt-agent --bin asbuilt-agent
    BIN=target/release
fi
BIN=$(cd "$BIN" && pwd)
ASBUILT=$BIN/${ASBUILT:-asbuilt}
AGENT=$BIN/${AGENT:-asbuilt-agent}
rm -rf "$OUT"
mkdir -p "$OUT/soak"

echo "== the reference: the demo, without kills"
"$ASBUILT" demo "${LOOP[@]}" --out "$OUT/reference" > "$OUT/reference.log" 2>&1
tail -n 3 "$OUT/reference.log"

echo "== the same job while the agent is killed $KILLS times (seed $SEED)"
cp "$OUT/reference/design.stl" "$OUT/soak/"
PREFIX=asbuilt-soak-$$
# The demo's agent, on its own services and without the view.
sed -e "s/^prefix = .*/prefix = \"$PREFIX\"/" -e '/^\[viewer\]/,/^rrd/d' \
    "$OUT/reference/agent.toml" > "$OUT/soak/agent.toml"
cd "$OUT/soak"
RANDOM=$SEED
AGENT_PID=
start() {
    "$AGENT" --config agent.toml > "agent-$1.log" 2>&1 &
    AGENT_PID=$!
}
start 0
for _ in $(seq 600); do grep -q "serving " agent-0.log && break; sleep 0.1; done
grep -q "serving " agent-0.log || { cat agent-0.log; exit 1; }
# The demo's job (its defaults and its defects on the wall), sent by the simulated cell.
"$ASBUILT" sim --prefix "$PREFIX" --findings --wait 60 "${LOOP[@]}" \
    --defect over-extrusion:layers=2-4,width=12mm \
    --defect bulge:x=-0.5,y=-0.0867,z=0.25,radius=0.1,height=15mm \
    --defect missing-segment:layer=18,x=0.45,y=0,length=0.25 \
    --defect height-drift:from=20,per-layer=0.5mm > sim.log 2>&1 &
SIM=$!
k=0
while [ "$k" -lt "$KILLS" ] && kill -0 "$SIM" 2> /dev/null; do
    # 0.3 to 2.2 s after the last start: during start-up, a station, or between stations
    # (the demo's job takes about 20 s without kills, so that ten fit in it).
    sleep "$((RANDOM % 2)).$((RANDOM % 10))"
    sleep 0.3
    kill -0 "$SIM" 2> /dev/null || break
    kill -9 "$AGENT_PID"
    wait "$AGENT_PID" 2> /dev/null || true
    k=$((k + 1))
    sleep "0.$((RANDOM % 10))"
    start "$k"
done
SIM_EXIT=0
wait "$SIM" || SIM_EXIT=$?
kill -TERM "$AGENT_PID"
wait "$AGENT_PID" 2> /dev/null || true
echo "kills: $k; the cell exited with $SIM_EXIT"
grep "interruption(s)" sim.log || echo "no interruption named by the cell"
PANICS=$( (grep -l "panicked" agent-*.log || true) | wc -l)
echo "agent logs with a panic: $PANICS"
"$ASBUILT" report recording --out report > report.log 2>&1 || {
    cat report.log
    exit 1
}
cd - > /dev/null

python3 - "$OUT" "$SIM_EXIT" "$k" "$KILLS" "$PANICS" <<'PY'
import glob, json, math, re, sys
out, sim_exit = sys.argv[1], int(sys.argv[2])
kills, asked, panics = int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5])
ok = True
def fail(msg):
    global ok
    ok = False
    print("FAIL:", msg)

if kills < asked:
    fail(f"{kills} kills of the {asked} asked: the job ended first")
if panics:
    fail(f"{panics} agent log(s) with a panic")

sim = open(f"{out}/soak/sim.log").read()
if sim_exit != 0:
    fail(f"the cell exited with {sim_exit}")
complete = re.findall(r"^\s+(\S+)\s+layer\s+\d+ Complete:", sim, re.M)
ref = json.load(open(f"{out}/reference/report.json"))
soak = json.load(open(f"{out}/soak/report/report.json"))
names = [s["id"] for s in ref["stations"]]
for n in names:
    if complete.count(n) != 1:
        fail(f"{n} ended Complete {complete.count(n)} time(s) in the cell's output")
print(f"stations: {len(names)}, each Complete once in the cell's output: "
      f"{all(complete.count(n) == 1 for n in names)}")

def same(a, b, path=""):
    """Equal, floats within 1e-6 relative."""
    if isinstance(a, float) or isinstance(b, float):
        if a is None or b is None:
            return a == b
        return a == b or math.isclose(a, b, rel_tol=1e-6, abs_tol=1e-12)
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(same(a[k], b[k], path + "." + k) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(same(x, y, path) for x, y in zip(a, b))
    return a == b

strip = lambda s: {k: v for k, v in s.items() if k != "attempt"}
ss = [strip(s) for s in soak["stations"]]
if [s["id"] for s in ss] != names:
    fail(f"stations differ: {[s['id'] for s in ss]}")
for a, b in zip(ref["stations"], ss):
    if not same(a, b):
        fail(f"station {a['id']} differs")
if not same(ref["overall"], soak["overall"]):
    fail("the overall section differs")
if not same(ref["findings"], soak["findings"]):
    fail("the findings differ")
print(f"findings: {len(soak['findings'])} scan layer(s), equal to the reference: "
      f"{same(ref['findings'], soak['findings'])}")
for w in soak["warnings"]:
    print("report warning:", w[:200])
    if "differ" in w:
        fail("what the agents told the cell live differs from what the recording gives again")
starts = []
for log in sorted(glob.glob(f"{out}/soak/agent-*.log"), key=lambda p: int(re.search(r"(\d+)\.log", p)[1])):
    text = open(log).read()
    m = re.search(r"serving .* ([0-9.]+) s after start", text)
    r = re.search(r"resume: job \d+ from (\d+) file\(s\): (\d+) report\(s\) recorded; (.*); in ([0-9.]+) s", text)
    starts.append((log.split("/")[-1], m and float(m[1]), r and r.groups()))
for name, t, r in starts:
    what = f"files {r[0]}, reports {r[1]}, {r[2]}, in {r[3]} s" if r else "nothing to resume"
    print(f"  {name}: serving {t if t is not None else 'never (killed first)'} s after start; {what}")
served = [t for _, t, _ in starts[1:] if t is not None]
if served:
    print(f"restart to serving: median {sorted(served)[len(served)//2]:.2f} s, max {max(served):.2f} s over {len(served)} restart(s)")
print("PASS" if ok else "FAILED")
sys.exit(0 if ok else 1)
PY
