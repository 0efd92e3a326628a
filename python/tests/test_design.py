"""Designs and C2M from Python, against analytic truth and brute force."""

import math

import numpy as np
import pytest

import asbuilt
from conftest import unit_cube


def cube():
    v, t = unit_cube()
    return asbuilt.Design.from_arrays(v, t)


def test_distances_to_a_cube_are_analytic():
    d = cube()
    pts = np.array([
        [0.3, 0.6, 1.2],    # above the top face: +0.2
        [0.3, 0.6, 0.9],    # inside, under the top: -0.1
        [1.1, 1.1, 0.5],    # beside a vertical edge: +sqrt(0.02)
        [1.1, 1.2, 1.3],    # beyond a corner
        [0.5, 0.5, 5.0],    # too far: no match
        [math.nan, 0, 0],   # not a point: rejected
    ])
    r = d.c2m(pts, max_distance=1.0, tolerance=0.15)
    dist = r["distance"]
    assert dist[0] == pytest.approx(0.2, abs=1e-12)
    assert dist[1] == pytest.approx(-0.1, abs=1e-12)
    assert dist[2] == pytest.approx(math.sqrt(0.02), abs=1e-12)
    assert dist[3] == pytest.approx(math.sqrt(0.01 + 0.04 + 0.09), abs=1e-12)
    assert math.isnan(dist[4]) and math.isnan(dist[5])
    assert list(r["feature"][:4]) == [1, 1, 2, 3]   # face, face, edge, vertex
    out = asbuilt.OUT_OF_TOLERANCE
    assert list(r["flags"]) == [out, 0, 0, out, asbuilt.NO_MATCH,
                                asbuilt.REJECTED]
    assert r["triangle"][4] == 2**32 - 1
    assert r["position"].shape == (6, 3)


def test_millimetres_are_scaled_and_arrays_come_back():
    v, t = unit_cube()
    d = asbuilt.Design.from_arrays(v * 1000.0, t, units="mm")
    lo, hi = d.bounds
    assert hi == pytest.approx([1.0, 1.0, 1.0])
    assert d.vertices.shape == (8, 3) and d.triangles.shape == (12, 3)
    assert d.triangles.dtype == np.uint32
    assert len(d) == 12


def test_c2m_equals_brute_force_on_the_bunny(bunny):
    rng = np.random.default_rng(7)
    lo, hi = (np.array(b) for b in bunny.bounds)
    pts = lo - 0.01 + (hi - lo + 0.02) * rng.random((3000, 3))
    r = bunny.c2m(pts, max_distance=0.01)
    v, t = bunny.vertices, bunny.triangles.astype(np.int64)
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    for i in range(0, 3000, 150):
        best = min(point_triangle(pts[i], a[k], b[k], c[k]) for k in range(len(t)))
        if best > 0.01:
            assert math.isnan(r["distance"][i])
        else:
            assert abs(abs(r["distance"][i]) - best) < 1e-9


def point_triangle(p, a, b, c):
    """Distance from p to triangle abc (Ericson, Real-Time Collision Detection 5.1.5)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = ab @ ap, ac @ ap
    if d1 <= 0 and d2 <= 0:
        return np.linalg.norm(ap)
    bp = p - b
    d3, d4 = ab @ bp, ac @ bp
    if d3 >= 0 and d4 <= d3:
        return np.linalg.norm(bp)
    vc = d1 * d4 - d3 * d2
    if vc <= 0 and d1 >= 0 and d3 <= 0:
        return np.linalg.norm(ap - ab * (d1 / (d1 - d3)))
    cp = p - c
    d5, d6 = ab @ cp, ac @ cp
    if d6 >= 0 and d5 <= d6:
        return np.linalg.norm(cp)
    vb = d5 * d2 - d1 * d6
    if vb <= 0 and d2 >= 0 and d6 <= 0:
        return np.linalg.norm(ap - ac * (d2 / (d2 - d6)))
    va = d3 * d6 - d5 * d4
    if va <= 0 and (d4 - d3) >= 0 and (d5 - d6) >= 0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return np.linalg.norm(p - (b + (c - b) * w))
    denom = 1.0 / (va + vb + vc)
    v, w = vb * denom, vc * denom
    return np.linalg.norm(p - (a + ab * v + ac * w))


def test_the_cut_design_is_capped_at_the_height():
    d = cube().cut(0.4)
    lo, hi = d.bounds
    assert hi[2] == pytest.approx(0.4)
    r = d.c2m(np.array([[0.5, 0.5, 0.5], [0.5, 0.5, 0.3]]), max_distance=1.0)
    assert r["distance"][0] == pytest.approx(0.1, abs=1e-12)    # above the cap: excess
    assert r["distance"][1] == pytest.approx(-0.1, abs=1e-12)
    assert r["triangle"][0] >= 12                                # a cap triangle


def test_bad_input_gets_a_clear_error(tmp_path):
    v, t = unit_cube()
    with pytest.raises(ValueError, match="unknown unit"):
        asbuilt.Design.from_arrays(v, t, units="inch")
    with pytest.raises(ValueError, match="refers to vertex 99"):
        asbuilt.Design.from_arrays(v, np.array([[0, 1, 99]]))
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        cube().c2m(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="max_distance"):
        cube().c2m(np.zeros((1, 3)), max_distance=-1.0)
    with pytest.raises(RuntimeError, match="nothing.stl"):
        asbuilt.Design.load(tmp_path / "nothing.stl", units="m")
    bad = tmp_path / "bad.stl"
    bad.write_bytes(b"solid x\nfacet normal 0 0 1\n outer loop\n vertex 1 2\n")
    with pytest.raises(RuntimeError, match="bad.stl"):
        asbuilt.Design.load(bad, units="m")
    with pytest.raises(RuntimeError, match="nothing is printed yet"):
        cube().cut(-1.0)


def test_stl_round_trip(tmp_path):
    path = tmp_path / "cube.stl"
    cube().write_stl(path)
    again = asbuilt.Design.load(path, units="m")
    assert len(again) == 12
    pts = np.array([[0.3, 0.6, 1.02]])
    assert again.c2m(pts)["distance"][0] == pytest.approx(0.02, abs=1e-7)
