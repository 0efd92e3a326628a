"""The deviation suite over arrays gives what `asbuilt inspect --method` gives."""

import numpy as np
import pytest

import asbuilt
from conftest import BUNNY_STATIONS


def test_suite_equals_inspect_on_the_bunny(tmp_path, bunny_path, bunny, bunny_recording):
    options = dict(tolerance=0.002, max_distance=0.005, spacing=0.004)
    report = asbuilt.inspect(bunny_path, "m", stations=BUNNY_STATIONS, out=tmp_path,
                             method=["coverage", "m3c2"], **options)
    rec = asbuilt.read_recording(bunny_recording)
    stations = [{"points": s.design_points, "origin": s.pose["translation"], "sigma": 0.001}
                for s in rec.stations]
    result = asbuilt.suite(bunny, stations, methods=["coverage", "m3c2"], **options)
    assert len(result["stations"]) == 10
    for mine, section in zip(result["stations"], report["stations"]):
        assert mine["coverage"] == section["coverage"]
        assert mine["m3c2"] == section["m3c2"]
    assert result["total"]["coverage"] == report["overall"]["coverage"]
    assert result["total"]["m3c2"] == report["overall"]["m3c2"]
    assert result["findings"] == report["findings"][0]
    s = result["samples"]
    n = len(s["m3c2"])
    assert n > 1000 and s["position"].shape == (n, 3) and s["normal"].shape == (n, 3)
    assert set(np.unique(s["class"])) <= {0, 1, 2, 3}
    # Most of the bunny is seen from ten stations; what is seen has an M3C2 distance.
    observed = s["class"] == 0
    assert observed.mean() > 0.5
    assert np.isfinite(s["m3c2"][observed]).mean() > 0.9


def test_suite_refuses_bad_stations_and_parameters(bunny):
    with pytest.raises(ValueError, match="station 0"):
        asbuilt.suite(bunny, [{"origin": [0, 0, 0]}])
    with pytest.raises(ValueError, match="tolerance"):
        asbuilt.suite(bunny, [], tolerance=0.0)
    with pytest.raises(ValueError, match="unknown"):
        asbuilt.suite(bunny, [], methods=["c2m", "icp"])
