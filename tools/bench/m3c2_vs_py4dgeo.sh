#!/usr/bin/env bash
# M3C2 side by side with py4dgeo (PyPI) on the same files: 2 M noisy points on the Stanford
# bunny (c2m_bench_inputs), about 100 k core points (the design's samples at 0.75 mm), a 2 mm
# cylinder radius, 10 mm half-length, the design's normals. asbuilt: `inspect --method m3c2`,
# whole process (it also runs C2M on every point and writes its files). py4dgeo: its M3C2 with
# asbuilt's core points and normals, the design's samples as the reference epoch, whole
# process (reading the PLY files included). Median of RUNS runs each, alternated; then the
# distances compared core point by core point. Not part of CI: it installs py4dgeo into
# target/bench-venv.
#
#   tools/bench/m3c2_vs_py4dgeo.sh            # RUNS=3 OUT=out/m3c2-bench
set -euo pipefail
cd "$(dirname "$0")/../.."
OUT=${OUT:-out/m3c2-bench}
# ASBUILT: another build to time (another revision's, for a before and after).
ASBUILT=${ASBUILT:-target/release/asbuilt}
RUNS=${RUNS:-3}
. tools/bench/inputs.sh
venv=target/bench-venv
[ -x "$venv/bin/python" ] || python3 -m venv "$venv"
"$venv/bin/pip" install --quiet --disable-pip-version-check py4dgeo numpy
BUNNY=../shared/data/stanford-bunny/bun_zipper.ply
asbuilt() {
    "$ASBUILT" inspect --design "$BUNNY" --units m --scan "$OUT/bunny_scan.ply" \
        --translation 0,0,0 --rotation-xyzw 0,0,0,1 --method m3c2 --spacing 0.00075 \
        --projection-diameter 0.004 --max-depth 0.01 --max-distance 0.01 \
        --out "$OUT/asbuilt" > "$OUT/asbuilt.log" 2>&1
}
py4dgeo() {
    "$venv/bin/python" tools/bench/m3c2_py4dgeo.py "$OUT/bunny_scan.ply" "$OUT/asbuilt/m3c2.ply" \
        0.002 0.01 "$OUT/py4dgeo.npy" > "$OUT/py4dgeo.log" 2>&1
}
seconds() { local t=$(date +%s.%N); "$@"; echo "$(date +%s.%N) - $t" | bc; }
asbuilt  # its m3c2.ply gives py4dgeo the core points
ours=(); theirs=()
for i in $(seq "$RUNS"); do
    ours+=("$(seconds asbuilt)")
    theirs+=("$(seconds py4dgeo)")
done
median() { printf '%s\n' "$@" | sort -n | awk '{a[NR]=$1} END {print a[int((NR+1)/2)]}'; }
a=$(median "${ours[@]}"); p=$(median "${theirs[@]}")
echo "asbuilt inspect --method m3c2: median $a s (${ours[*]})"
echo "py4dgeo M3C2:                 median $p s (${theirs[*]})"
echo "asbuilt is $(echo "scale=2; $p / $a" | bc)x py4dgeo"
"$venv/bin/python" - "$OUT" <<'PY'
import sys, numpy as np
sys.path.insert(0, "tools/bench")
from m3c2_py4dgeo import read_ply
out = sys.argv[1]
ours = read_ply(f"{out}/asbuilt/m3c2.ply")["distance"].astype(np.float64)
theirs = np.load(f"{out}/py4dgeo.npy")
both = np.isfinite(ours) & np.isfinite(theirs)
d = np.abs(ours[both] - theirs[both])
print(f"core points: {len(ours)}, with a distance in both: {both.sum()} "
      f"(asbuilt only {(np.isfinite(ours) & ~np.isfinite(theirs)).sum()}, "
      f"py4dgeo only {(~np.isfinite(ours) & np.isfinite(theirs)).sum()})")
print(f"|asbuilt - py4dgeo|: median {np.median(d) * 1e3:.4f} mm, p95 "
      f"{np.percentile(d, 95) * 1e3:.4f} mm")
PY
