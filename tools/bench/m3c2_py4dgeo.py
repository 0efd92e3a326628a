"""py4dgeo's M3C2 on the job `m3c2_vs_py4dgeo.sh` gives asbuilt: the scan (a binary PLY of
doubles) against the design's samples as the reference epoch, at asbuilt's core points with
asbuilt's design normals (read from its m3c2.ply), the same cylinder. Whole process: reading
the files, building the trees, the run. Writes the distances (.npy) for the comparison.

    python m3c2_py4dgeo.py SCAN.ply M3C2.ply RADIUS MAX_DEPTH OUT.npy
"""

import sys

import numpy as np
import py4dgeo


def read_ply(path):
    """A binary little-endian PLY's vertex element as a structured array."""
    with open(path, "rb") as f:
        props, count = [], 0
        while True:
            line = f.readline().decode("ascii").strip()
            if line.startswith("element vertex"):
                count = int(line.split()[-1])
            elif line.startswith("property"):
                _, kind, name = line.split()
                props.append((name, {"double": "<f8", "float": "<f4", "uint": "<u4",
                                     "int": "<i4", "uchar": "u1", "ushort": "<u2"}[kind]))
            elif line == "end_header":
                break
        return np.fromfile(f, dtype=np.dtype(props), count=count)


def main():
    scan_path, core_path, radius, depth, out = sys.argv[1:6]
    # py4dgeo logs to py4dgeo.log in the working folder unless told: keep it beside the output.
    py4dgeo.set_py4dgeo_logfile(out + ".log")
    scan = read_ply(scan_path)
    core = read_ply(core_path)
    xyz = np.stack([scan["x"], scan["y"], scan["z"]], axis=1)
    corepoints = np.stack([core["x"], core["y"], core["z"]], axis=1)
    normals = np.stack([core["nx"], core["ny"], core["nz"]], axis=1).astype(np.float64)
    reference = py4dgeo.Epoch(corepoints.copy())
    epoch = py4dgeo.Epoch(xyz)
    m3c2 = py4dgeo.M3C2(epochs=(reference, epoch), corepoints=corepoints,
                        cyl_radius=float(radius), max_distance=float(depth),
                        corepoint_normals=normals)
    distances, _ = m3c2.run()
    np.save(out, distances)


if __name__ == "__main__":
    main()
