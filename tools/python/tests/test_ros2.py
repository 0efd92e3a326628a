"""ROS 2 bags as a cell records them, written by an independent writer (the pure-Python
`rosbags`), in both storages: the scanner on the robot's flange (a static transform) moved by the
robot (`/tf` at 50 Hz), a cloud per station stamped between two transforms. Each station's
results equal `inspect` given the same points and the pose the transform tree gives directly."""

import math

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

import asbuilt

TS = get_typestore(Stores.ROS2_JAZZY)
T = TS.types
T0 = 100.0  # the bag's clock, seconds
STAMPS = [T0 + 1.013, T0 + 4.517, T0 + 8.259]
MOUNT = ((0.05, 0.0, 0.1), (0.0, math.sin(0.0873), 0.0, math.cos(0.0873)))  # x, y, z, w


def qmul(a, b):
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz)


def rotate(q, v):
    x, y, z, _ = qmul(qmul(q, (v[0], v[1], v[2], 0.0)), (-q[0], -q[1], -q[2], q[3]))
    return (x, y, z)


def compose(a, b):
    """a ∘ b for poses (translation, quaternion xyzw)."""
    t = rotate(a[1], b[0])
    return ((a[0][0] + t[0], a[0][1] + t[1], a[0][2] + t[2]), qmul(a[1], b[1]))


def flange(t):
    """The robot's flange in the world at time t: on a circle around the part, turning."""
    a = 0.2 * (t - T0)
    half = (a + math.pi) / 2
    return ((0.5 + 1.5 * math.cos(a), 0.5 + 1.5 * math.sin(a), 1.2),
            (0.0, 0.0, math.sin(half), math.cos(half)))


def slerp(a, b, s):
    dot = sum(x * y for x, y in zip(a, b))
    theta = math.acos(min(1.0, dot))
    if theta < 1e-12:
        return a
    wa, wb = math.sin((1 - s) * theta) / math.sin(theta), math.sin(s * theta) / math.sin(theta)
    return tuple(wa * x + wb * y for x, y in zip(a, b))


def tf_samples():
    return [T0 + k * 0.02 for k in range(501)]


def interpolated(t):
    """The flange as the transform tree interpolates it at t (linear, slerp)."""
    times = tf_samples()
    k = max(i for i, s in enumerate(times) if s <= t)
    a, b = flange(times[k]), flange(times[k + 1])
    s = (t - times[k]) / (times[k + 1] - times[k])
    tr = tuple(x + (y - x) * s for x, y in zip(a[0], b[0]))
    return tr, slerp(a[1], b[1], s)


def inverse(p):
    q = (-p[1][0], -p[1][1], -p[1][2], p[1][3])
    t = rotate(q, p[0])
    return ((-t[0], -t[1], -t[2]), q)


def box_stl(path):
    """A 1 m box from the origin."""
    v = [(x, y, z) for x in (0, 1) for y in (0, 1) for z in (0, 1)]
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    lines = ["solid box"]
    for a, b, c, d in quads:
        for tri in ((a, b, c), (a, c, d)):
            lines += ["facet normal 0 0 0", "outer loop"]
            lines += [f"vertex {v[i][0]} {v[i][1]} {v[i][2]}" for i in tri]
            lines += ["endloop", "endfacet"]
    lines.append("endsolid box")
    path.write_text("\n".join(lines))


def world_points(seed, n=3000):
    """Points on the box's top and its x = 1 face, with a 3 mm bump and 0.5 mm noise."""
    rng = np.random.default_rng(seed)
    u, v = rng.uniform(0.05, 0.95, n), rng.uniform(0.05, 0.95, n)
    top = rng.random(n) < 0.5
    bump = np.where((u - 0.5) ** 2 + (v - 0.5) ** 2 < 0.01, 0.003, 0.0)
    noise = rng.normal(0.0, 0.0005, n)
    x = np.where(top, u, 1.0 + bump + noise)
    y = np.where(top, v, u)
    z = np.where(top, 1.0 + bump + noise, v)
    return np.stack([x, y, z], axis=1)


def in_scanner(points, pose):
    inv = inverse(pose)
    return np.array([np.add(rotate(inv[1], p), inv[0]) for p in points], dtype=np.float32)


def cloud(stamp, pts, style):
    """A PointCloud2 of `pts` (float32, scanner frame) in one of three layouts."""
    n = len(pts)
    intensity = np.linspace(0, 1, n, dtype=np.float32)
    F = T["sensor_msgs/msg/PointField"]
    if style == 0:  # float32 x, y, z, intensity, little endian
        rec = np.zeros(n, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("i", "<f4")])
        fields = [F(name=c, offset=4 * k, datatype=7, count=1) for k, c in enumerate("xyz")]
        fields.append(F(name="intensity", offset=12, datatype=7, count=1))
        big, height, step = False, 1, 16
    elif style == 1:  # intensity first, then float64 x, y, z
        rec = np.zeros(n, dtype=[("i", "<f4"), ("pad", "<f4"), ("x", "<f8"), ("y", "<f8"),
                                 ("z", "<f8")])
        fields = [F(name="intensity", offset=0, datatype=7, count=1)]
        fields += [F(name=c, offset=8 + 8 * k, datatype=8, count=1) for k, c in enumerate("xyz")]
        big, height, step = False, 1, 32
    else:  # big endian float32 with padding, two rows
        rec = np.zeros(n, dtype=[("x", ">f4"), ("y", ">f4"), ("z", ">f4"), ("pad", ">f4"),
                                 ("i", ">f4")])
        fields = [F(name=c, offset=4 * k, datatype=7, count=1) for k, c in enumerate("xyz")]
        fields.append(F(name="intensity", offset=16, datatype=7, count=1))
        big, height, step = True, 2, 20
    rec["x"], rec["y"], rec["z"], rec["i"] = pts[:, 0], pts[:, 1], pts[:, 2], intensity
    width = n // height
    data = rec.tobytes()
    header = T["std_msgs/msg/Header"](
        stamp=T["builtin_interfaces/msg/Time"](sec=int(stamp), nanosec=round(stamp % 1 * 1e9)),
        frame_id="scanner")
    return T["sensor_msgs/msg/PointCloud2"](
        header=header, height=height, width=width, fields=fields, is_bigendian=big,
        point_step=step, row_step=width * step, data=np.frombuffer(data, dtype=np.uint8),
        is_dense=True)


def transform(stamp, parent, child, pose):
    G = T
    return G["geometry_msgs/msg/TransformStamped"](
        header=G["std_msgs/msg/Header"](
            stamp=G["builtin_interfaces/msg/Time"](sec=int(stamp),
                                                    nanosec=round(stamp % 1 * 1e9)),
            frame_id=parent),
        child_frame_id=child,
        transform=G["geometry_msgs/msg/Transform"](
            translation=G["geometry_msgs/msg/Vector3"](x=pose[0][0], y=pose[0][1], z=pose[0][2]),
            rotation=G["geometry_msgs/msg/Quaternion"](x=pose[1][0], y=pose[1][1],
                                                        z=pose[1][2], w=pose[1][3])))


def write_bag(path, storage, clouds):
    tf_type, pc_type = "tf2_msgs/msg/TFMessage", "sensor_msgs/msg/PointCloud2"
    with Writer(path, version=8, storage_plugin=storage) as w:
        static = w.add_connection("/tf_static", tf_type, typestore=TS)
        dynamic = w.add_connection("/tf", tf_type, typestore=TS)
        points = w.add_connection("/scanner/points", pc_type, typestore=TS)
        msg = T[tf_type](transforms=[transform(T0, "flange", "scanner", MOUNT)])
        w.write(static, int(T0 * 1e9), TS.serialize_cdr(msg, tf_type))
        events = [(s, 0, None) for s in tf_samples()] + [(s, 1, c) for s, c in clouds]
        for stamp, kind, c in sorted(events, key=lambda e: (e[0], e[1])):
            if kind == 0:
                msg = T[tf_type](transforms=[transform(stamp, "world", "flange", flange(stamp))])
                w.write(dynamic, int(stamp * 1e9), TS.serialize_cdr(msg, tf_type))
            else:
                w.write(points, int(stamp * 1e9), TS.serialize_cdr(c, pc_type))


@pytest.fixture(scope="module")
def job(tmp_path_factory):
    """The box, three stations' scanner-frame points, their poses, and what inspect makes of
    them given directly."""
    root = tmp_path_factory.mktemp("ros2")
    design = root / "box.stl"
    box_stl(design)
    clouds, lines = [], []
    for k, stamp in enumerate(STAMPS):
        pose = compose(interpolated(stamp), MOUNT)
        pts = in_scanner(world_points(k), pose)
        clouds.append((stamp, cloud(stamp, pts, k)))
        scan = root / f"s{k}.xyz"
        scan.write_text("\n".join(" ".join(repr(float(v)) for v in p) for p in pts))
        lines += ["[[station]]", f'id = "points-{k + 1:04}"', f'scan = "{scan.name}"',
                  f"translation = [{', '.join(repr(v) for v in pose[0])}]",
                  f"rotation_xyzw = [{', '.join(repr(v) for v in pose[1])}]", ""]
    stations = root / "stations.toml"
    stations.write_text("\n".join(lines))
    direct = asbuilt.inspect(design, "m", stations=stations, max_distance=0.05)
    return root, design, clouds, direct


def same_stations(got, want):
    assert [s["id"] for s in got["stations"]] == [s["id"] for s in want["stations"]]
    for g, w in zip(got["stations"], want["stations"]):
        for key, value in w.items():
            if key == "scan":
                continue
            if isinstance(value, float):
                # The same points, placed by the same pose: equal to rounding (nm).
                assert g[key] == pytest.approx(value, abs=1e-9), (g["id"], key)
            else:
                assert g[key] == value, (g["id"], key)


@pytest.mark.parametrize("storage", [StoragePlugin.MCAP, StoragePlugin.SQLITE3])
def test_a_bag_s_stations_equal_inspect_given_their_poses_directly(job, storage):
    root, design, clouds, direct = job
    bag = root / f"bag-{storage.name.lower()}"
    write_bag(bag, storage, clouds)
    got = asbuilt.inspect(design, "m", ros2=bag, max_distance=0.05)
    assert len(got["stations"]) == 3
    same_stations(got, direct)
    # The bump is seen: the top face's points stand up to 3 mm out.
    assert max(s["max"] for s in got["stations"]) > 0.0025


def test_a_bag_s_troubles_are_named(job, tmp_path):
    root, design, clouds, _ = job
    bag = tmp_path / "bag"
    write_bag(bag, StoragePlugin.MCAP, clouds)
    with pytest.raises(RuntimeError, match="no PointCloud2 messages on /lidar"):
        asbuilt.inspect(design, "m", ros2=bag, cloud_topic="/lidar")
    # A design frame that is not in the tree fails every station, each with the reason named in
    # the report, and the job goes on to its report.
    r = asbuilt.inspect(design, "m", ros2=bag, frame="map")
    assert r["stations"] == []
    not_placed = [w for w in r["warnings"] if "was not inspected" in w]
    assert len(not_placed) == 3, r["warnings"]
    assert 'frame "map" is not in the bag\'s transform tree (its frames: flange, scanner, world)' \
        in not_placed[0]
    damaged = tmp_path / "damaged.mcap"
    mcap = next(bag.glob("*.mcap")).read_bytes()
    damaged.write_bytes(mcap[: len(mcap) // 2] + b"\xff" * 64)
    with pytest.raises(RuntimeError, match="damaged"):
        asbuilt.inspect(design, "m", ros2=damaged)
