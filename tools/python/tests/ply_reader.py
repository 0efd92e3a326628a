"""A reader for the binary PLY files asbuilt writes, for the tests and the benchmarks."""

import numpy as np

PLY_TYPES = {"double": "<f8", "float": "<f4", "uint": "<u4", "ushort": "<u2", "uchar": "u1",
             "float64": "<f8", "float32": "<f4", "uint32": "<u4", "uint16": "<u2",
             "uint8": "u1", "int": "<i4", "int32": "<i4"}


def read_ply(path):
    """A binary little-endian PLY's first element as a NumPy structured array."""
    with open(path, "rb") as f:
        fields, count = [], None
        line = f.readline()
        assert line.strip() == b"ply", f"{path} is not a PLY file"
        while True:
            line = f.readline().decode("ascii").strip()
            if line == "end_header":
                break
            words = line.split()
            if words[0] == "format":
                assert words[1] == "binary_little_endian", line
            elif words[0] == "element":
                if count is not None:
                    break
                count = int(words[2])
            elif words[0] == "property" and count is not None:
                fields.append((words[2], PLY_TYPES[words[1]]))
        return np.fromfile(f, dtype=np.dtype(fields), count=count)
