"""The command line's code from Python: `asbuilt.inspect` and C2M give the same bits."""

import numpy as np
import pytest

import asbuilt
from ply_reader import read_ply
from conftest import BUNNY_STATIONS


def test_c2m_equals_inspect_on_the_bunny(tmp_path, bunny_path, bunny):
    report = asbuilt.inspect(bunny_path, "m", stations=BUNNY_STATIONS, max_distance=0.005,
                             out=tmp_path)
    assert len(report["stations"]) == 10
    ply = read_ply(tmp_path / "deviations.ply")
    assert len(ply) > 300_000
    pts = np.stack([ply["x"], ply["y"], ply["z"]], axis=1)
    r = bunny.c2m(pts, max_distance=0.005, tolerance=report["parameters"]["tolerance_m"])
    # deviations.ply keeps the distance as float32: the same bits at the file's precision.
    np.testing.assert_array_equal(r["distance"].astype(np.float32), ply["c2m"])
    np.testing.assert_array_equal(r["triangle"], ply["triangle"])
    np.testing.assert_array_equal(r["feature"], ply["feature"])
    np.testing.assert_array_equal(r["flags"], ply["flags"])
    matched = np.isfinite(r["distance"]).sum()
    assert matched == report["overall"]["matched"]


def test_inspect_takes_typed_keywords_and_refuses_bad_ones(bunny_path):
    # Keywords are the command's flags, checked by Python's call and the flags' own parsers.
    with pytest.raises(TypeError, match="no_such_flag"):
        asbuilt.inspect(bunny_path, "m", stations=BUNNY_STATIONS, no_such_flag=1)
    with pytest.raises(ValueError, match="units"):
        asbuilt.inspect(bunny_path, "inches", stations=BUNNY_STATIONS)
    with pytest.raises(ValueError, match="method"):
        asbuilt.inspect(bunny_path, "m", stations=BUNNY_STATIONS, method=["c2m", "icp"])
    with pytest.raises(ValueError, match="limit"):
        asbuilt.inspect(bunny_path, "m", stations=BUNNY_STATIONS, limit=["wobble=3mm"])
    with pytest.raises(TypeError):
        asbuilt.inspect(bunny_path, "m", stations=BUNNY_STATIONS, tolerance="5mm")
    with pytest.raises(RuntimeError, match="tolerance"):
        asbuilt.inspect(bunny_path, "m", stations=BUNNY_STATIONS, tolerance=-1)
    with pytest.raises(RuntimeError, match="not both"):
        asbuilt.inspect(bunny_path, "m", stations=BUNNY_STATIONS, scan=bunny_path)
    with pytest.raises(RuntimeError, match="--no-maps"):
        asbuilt.inspect(bunny_path, "m", stations=BUNNY_STATIONS, png=True, no_maps=True)


def test_inspect_methods_as_a_list_or_a_string_are_the_same(tmp_path, bunny_path):
    scan = BUNNY_STATIONS.parent / "../../../../shared/data/stanford-bunny/scans/bun000.ply"
    a = asbuilt.inspect(bunny_path, "m", scan=scan, translation=[0, 0, 0],
                        rotation_xyzw=[0, 0, 0, 1], method=["coverage", "c2m"])
    b = asbuilt.inspect(bunny_path, "m", scan=scan, translation=[0, 0, 0],
                        rotation_xyzw=[0, 0, 0, 1], method="c2m,coverage")
    assert a["methods"] == b["methods"] == ["c2m", "coverage"]
    assert a["overall"] == b["overall"]
    # Without the maps, the same verdicts and statistics.
    c = asbuilt.inspect(bunny_path, "m", scan=scan, translation=[0, 0, 0],
                        rotation_xyzw=[0, 0, 0, 1], method="c2m,coverage", no_maps=True)
    assert c["overall"] == a["overall"]


def test_argv_spells_flags_as_the_command_line():
    assert asbuilt.argv(max_distance=0.01, png=True, ascii=False, method=["c2m", "m3c2"],
                        limit=["width=3mm", "creep=1mm"], rerun=None) == [
        "--max-distance=0.01", "--png", "--method=c2m,m3c2",
        "--limit=width=3mm", "--limit=creep=1mm"]
    assert asbuilt.argv(translation=[-1, 0, 2.5]) == ["--translation=-1,0,2.5"]
