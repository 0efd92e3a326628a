"""asbuilt.archive on a LocalCluster of 1 worker against 2, over the same recordings: the
whole call (cluster start, every job's report, the Parquet tables and the fleet page), median
of `--runs` runs each, alternated. Not part of CI.

    python tools/python/bench/archive_workers.py RECORDING... [--runs 3]
"""

import argparse
import statistics
import tempfile
import time

import asbuilt.archive as archive


def main():
    p = argparse.ArgumentParser()
    p.add_argument("recordings", nargs="+")
    p.add_argument("--runs", type=int, default=3)
    args = p.parse_args()
    jobs = archive.find_jobs(args.recordings)
    print(f"{len(jobs)} job(s): " + ", ".join(f"{j.name} ({len(j.files)} file(s))" for j in jobs))
    times = {1: [], 2: []}
    for _ in range(args.runs):
        for workers in (1, 2):
            with tempfile.TemporaryDirectory() as out:
                t = time.perf_counter()
                r = archive.analyse(args.recordings, out, workers=workers, progress=False)
                times[workers].append(time.perf_counter() - t)
                assert r.jobs == len(jobs)
    one, two = statistics.median(times[1]), statistics.median(times[2])
    print(f"1 worker: median {one:.1f} s {[round(x, 1) for x in times[1]]}")
    print(f"2 workers: median {two:.1f} s {[round(x, 1) for x in times[2]]}")
    print(f"2 workers / 1 worker: {one / two:.2f}x faster")


if __name__ == "__main__":
    main()
