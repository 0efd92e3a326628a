#!/usr/bin/env bash
# The agent on a 1,004,000-triangle free-form design through a three-scan-layer demo: how long
# each new printed height takes to prepare (the station's chunks wait that long, the event loop
# does not) and the longest gap between the agent's health lines. Not part of CI.
#
#   tools/bench/height_switch.sh            # OUT=out/height-switch
set -euo pipefail
cd "$(dirname "$0")/../.."
OUT=${OUT:-out/height-switch}
INPUTS=${INPUTS:-out/c2m-bench}
cargo build --release --locked -p asbuilt-tools --bin asbuilt --example c2m_bench_inputs
[ -f "$INPUTS/column.stl" ] || target/release/examples/c2m_bench_inputs "$INPUTS"
target/release/asbuilt demo --part "$INPUTS/column.stl" --units m --layer-height 0.02 \
    --scan-after 10,30,50 --out "$OUT" "$@"
python3 - "$OUT/agent.log" <<'PY'
import re, sys
from datetime import datetime
t = lambda line: datetime.strptime(line[:23], "%Y-%m-%dT%H:%M:%S.%f")
lines = open(sys.argv[1]).read().splitlines()
health = [t(l) for l in lines if " health: " in l]
ready = [float(m.group(1)) for l in lines if (m := re.search(r"ready in ([0-9.]+) ms", l))]
section = [float(m.group(1)) for l in lines if (m := re.search(r"triangles(?: and the cut mesh with its edges)? ([0-9.]+) ms", l))]
mesh = [float(m.group(1)) for l in lines if (m := re.search(r"samples, M3C2 and coverage ([0-9.]+) ms", l))]
design = [l for l in lines if "index" in l and "triangles" in l][:1]
print("\n".join(design))
print(f"printed heights prepared: {len(ready)}, in ms (chunks held that long): {ready}")
print(f"  of which the section (C2M, lines of sight) with, beside it, the cut mesh and its edges: {section} ms; then the findings' samples, M3C2 and coverage set-up: {mesh} ms")
gaps = [(b - a).total_seconds() for a, b in zip(health, health[1:])]
print(f"health lines: {len(health)}, longest gap {max(gaps, default=0):.2f} s")
PY
