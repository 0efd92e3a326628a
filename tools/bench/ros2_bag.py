"""Writes a ROS 2 bag as a cell with a scanner on the robot's flange records it, with the
independent pure-Python `rosbags` writer: `/tf_static` (flange -> scanner), `/tf` at 50 Hz
(world -> flange, the robot moving), and PointCloud2 clouds of POINTS points (x, y, z,
intensity as float32) at 10 Hz on /scanner/points, until the bag holds about SIZE_MB.

    python ros2_bag.py OUT_DIR SIZE_MB [POINTS] [mcap|sqlite3]
"""

import math
import sys

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

TS = get_typestore(Stores.ROS2_JAZZY)
T = TS.types
TF, PC = "tf2_msgs/msg/TFMessage", "sensor_msgs/msg/PointCloud2"


def stamp(t):
    return T["builtin_interfaces/msg/Time"](sec=int(t), nanosec=int(round(t % 1 * 1e9)) % 10**9)


def transform(t, parent, child, xyz, yaw):
    G = T
    return G["geometry_msgs/msg/TransformStamped"](
        header=G["std_msgs/msg/Header"](stamp=stamp(t), frame_id=parent), child_frame_id=child,
        transform=G["geometry_msgs/msg/Transform"](
            translation=G["geometry_msgs/msg/Vector3"](x=xyz[0], y=xyz[1], z=xyz[2]),
            rotation=G["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw / 2),
                                                        w=math.cos(yaw / 2))))


def main():
    out, size_mb = sys.argv[1], float(sys.argv[2])
    points = int(sys.argv[3]) if len(sys.argv) > 3 else 65536
    storage = StoragePlugin.SQLITE3 if sys.argv[4:] == ["sqlite3"] else StoragePlugin.MCAP
    clouds = max(1, int(size_mb * 1e6 // (points * 16)))
    rng = np.random.default_rng(1)
    F = T["sensor_msgs/msg/PointField"]
    fields = [F(name=c, offset=4 * k, datatype=7, count=1) for k, c in enumerate("xyz")]
    fields.append(F(name="intensity", offset=12, datatype=7, count=1))
    t0 = 1000.0
    with Writer(out, version=8, storage_plugin=storage) as w:
        static = w.add_connection("/tf_static", TF, typestore=TS)
        dynamic = w.add_connection("/tf", TF, typestore=TS)
        cloud_conn = w.add_connection("/scanner/points", PC, typestore=TS)
        msg = T[TF](transforms=[transform(t0, "flange", "scanner", (0.05, 0.0, 0.1), 0.0)])
        w.write(static, int(t0 * 1e9), TS.serialize_cdr(msg, TF))
        end = t0 + clouds / 10 + 0.1
        k, t = 0, t0
        data = rng.uniform(-0.5, 0.5, (points, 4)).astype(np.float32)
        data[:, 2] += 1.5
        for n in range(clouds):
            tc = t0 + 0.05 + n / 10
            while t <= min(tc + 0.02, end):
                a = 0.1 * (t - t0)
                msg = T[TF](transforms=[transform(t, "world", "flange",
                                                  (1.5 * math.cos(a), 1.5 * math.sin(a), 1.0),
                                                  a + math.pi)])
                w.write(dynamic, int(t * 1e9), TS.serialize_cdr(msg, TF))
                k += 1
                t = t0 + k * 0.02
            cloud = T[PC](header=T["std_msgs/msg/Header"](stamp=stamp(tc), frame_id="scanner"),
                          height=1, width=points, fields=fields, is_bigendian=False,
                          point_step=16, row_step=16 * points,
                          data=np.frombuffer(data.tobytes(), dtype=np.uint8), is_dense=True)
            w.write(cloud_conn, int(tc * 1e9), TS.serialize_cdr(cloud, PC))
    print(f"{out}: {clouds} clouds of {points} points ({clouds * points} points), "
          f"{k} transforms")


if __name__ == "__main__":
    main()
