"""C2M from Python next to the command line on the same files, in one run.

    tools/bench/c2m_vs_cloudcompare.sh          # makes out/c2m-bench/bunny_{scan,shuffled}.ply
    pip install ./tools/python                  # a release build of the package
    python tools/python/bench/c2m_throughput.py [--inputs out/c2m-bench] [--runs 5]

For each point file: `Design.c2m` on the points already in memory (points/s, median of runs,
the index built before), the whole Python job (read the PLY with NumPy, load the design, build
the index, C2M), and `asbuilt inspect` as a whole process (median of runs) with its station's
points/s (read, C2M and write, from its station line). Checks that Python's distances,
triangles and flags equal inspect's deviations.ply. Not part of CI.
"""

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

import asbuilt

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))
from ply_reader import read_ply  # noqa: E402

BUNNY = "../shared/data/stanford-bunny/bun_zipper.ply"
MAX_DISTANCE = 0.005
TOLERANCE = 0.0005


def load_points(path):
    """The file's points as the command line sees them: scan points are float32 in asbuilt
    (a scanner's precision), so doubles in the file are rounded the same way here."""
    ply = read_ply(path)
    xyz = np.stack([ply["x"], ply["y"], ply["z"]], axis=1)
    return xyz.astype(np.float32).astype(np.float64)


def python_job(points_path):
    t = time.perf_counter()
    pts = load_points(points_path)
    design = asbuilt.Design.load(BUNNY, units="m")
    r = design.c2m(pts, max_distance=MAX_DISTANCE, tolerance=TOLERANCE)
    return time.perf_counter() - t, r


def cli_job(exe, points_path, out):
    t = time.perf_counter()
    p = subprocess.run(
        [exe, "inspect", "--design", BUNNY, "--units", "m", "--scan", points_path,
         "--translation", "0,0,0", "--rotation-xyzw", "0,0,0,1", "--tolerance", str(TOLERANCE),
         "--max-distance", str(MAX_DISTANCE), "--out", out],
        capture_output=True, text=True)
    wall = time.perf_counter() - t
    if p.returncode not in (0, 1):
        raise SystemExit(f"asbuilt inspect failed:\n{p.stderr}")
    # The station line ends with the station's seconds (read, C2M, write): "(0.48 s)".
    station = [float(m) for m in re.findall(r"^station .*\((\d+\.\d+) s\)\s*$", p.stderr, re.M)]
    return wall, station[-1] if station else float("nan")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--inputs", default="out/c2m-bench")
    ap.add_argument("--asbuilt", default="target/release/asbuilt")
    ap.add_argument("--runs", type=int, default=5)
    args = ap.parse_args()
    design = asbuilt.Design.load(BUNNY, units="m")
    t = time.perf_counter()
    design.index_stats(MAX_DISTANCE)
    print(f"bunny index: {time.perf_counter() - t:.3f} s")
    print(f"{'file':<20} {'points':>9} {'py c2m Mpt/s':>13} {'py job s':>9} "
          f"{'cli job s':>10} {'cli station Mpt/s':>18} {'py job / cli job':>17}")
    for name in ("bunny_scan.ply", "bunny_shuffled.ply"):
        path = os.path.join(args.inputs, name)
        pts = load_points(path)
        calls, py_jobs, cli_walls, cli_stations = [], [], [], []
        with tempfile.TemporaryDirectory() as out:
            for _ in range(args.runs):
                t = time.perf_counter()
                r = design.c2m(pts, max_distance=MAX_DISTANCE, tolerance=TOLERANCE)
                calls.append(time.perf_counter() - t)
                py_jobs.append(python_job(path)[0])
                wall, station = cli_job(args.asbuilt, path, out)
                cli_walls.append(wall)
                cli_stations.append(station)
            ply = read_ply(os.path.join(out, "deviations.ply"))
        same = (np.array_equal(r["distance"].astype(np.float32), ply["c2m"], equal_nan=True)
                and np.array_equal(r["triangle"], ply["triangle"])
                and np.array_equal(r["flags"], ply["flags"]))
        call, job = statistics.median(calls), statistics.median(py_jobs)
        wall, station = statistics.median(cli_walls), statistics.median(cli_stations)
        print(f"{name:<20} {len(pts):>9} {len(pts) / call / 1e6:>13.2f} {job:>9.2f} "
              f"{wall:>10.2f} {len(pts) / station / 1e6:>18.2f} {job / wall:>17.2f}"
              f"   same as deviations.ply: {same}")
        if not same:
            raise SystemExit("Python and the command line differ")


if __name__ == "__main__":
    main()
