"""A recording read back from Python equals `asbuilt report`, station by station."""

import json

import numpy as np

import asbuilt


def quaternion_rotate(q, v):
    x, y, z, w = q
    u = np.array([x, y, z])
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def test_read_recording_equals_report(tmp_path, bunny_recording, bunny):
    assert asbuilt.run("report", bunny_recording, "--out", tmp_path) == 0
    with open(tmp_path / "report.json", encoding="utf-8") as f:
        expected = json.load(f)
    rec = asbuilt.read_recording(bunny_recording)
    assert rec.report == expected
    assert len(rec.stations) == 10
    total = 0
    for st, section in zip(rec.stations, expected["stations"]):
        assert st.name == section["id"]
        n = len(st.scan_points)
        assert st.scan_points.dtype == np.float32 and st.scan_points.shape == (n, 3)
        dev = st.deviations
        assert len(dev["distance"]) == n     # every chunk was inspected
        assert st.report["points_received"] == n
        # Design frame = the recorded pose applied to the scanner-frame points.
        pose = st.pose
        v = st.scan_points[:50].astype(np.float64)
        placed = np.array([quaternion_rotate(pose["rotation_xyzw"], p) for p in v])
        placed += np.array(pose["translation"])
        np.testing.assert_allclose(st.design_points[:50], placed, atol=1e-12)
        # The agent's C2M of those points, bit for bit in float64.
        ok = (dev["flags"] & asbuilt.REJECTED) == 0
        r = bunny.c2m(st.design_points[ok], max_distance=expected["parameters"]["max_distance_m"],
                      tolerance=expected["parameters"]["tolerance_m"])
        np.testing.assert_array_equal(r["distance"], dev["distance"][ok])
        np.testing.assert_array_equal(r["triangle"], dev["triangle"][ok])
        np.testing.assert_array_equal(r["flags"], dev["flags"][ok])
        total += n
    assert total == expected["overall"]["points"]


def test_a_file_that_is_not_a_recording_is_refused(tmp_path):
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"\x89MCAP0\r\n" + b"\0" * 64)
    try:
        asbuilt.read_recording(bad)
    except RuntimeError as e:
        assert "bad.mcap" in str(e)
    else:
        raise AssertionError("a damaged recording was read")


def test_reading_a_recording_keeps_the_agents_progress_lines_to_itself(capfd, tmp_path,
                                                                       bunny_recording):
    # The command line shows the lifecycle's lines as it replays the recording ...
    assert asbuilt.run("report", bunny_recording, "--out", tmp_path) == 0
    assert " INFO " in capfd.readouterr().err
    # ... Python's reader does not, and the command line still does afterwards.
    asbuilt.read_recording(bunny_recording)
    assert " INFO " not in capfd.readouterr().err
    assert asbuilt.run("report", bunny_recording, "--out", tmp_path) == 0
    assert " INFO " in capfd.readouterr().err
