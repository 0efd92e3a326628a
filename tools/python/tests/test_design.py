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
    for i in range(0, 3000, 30):
        best = point_triangles(pts[i], a, b, c).min()
        if best > 0.01:
            assert math.isnan(r["distance"][i])
        else:
            assert abs(abs(r["distance"][i]) - best) < 1e-9


def point_triangles(p, a, b, c):
    """Distance from p to each triangle (a[k], b[k], c[k]): to its plane where p projects
    inside it, else to the nearest of its edges. Not the Voronoi regions of Ericson's closest
    point that C2M walks, so the two agree only if both are right."""
    def to_edges(s, e):
        d = e - s
        dd = np.einsum("ij,ij->i", d, d)
        t = np.einsum("ij,ij->i", p - s, d) / np.where(dd > 0, dd, 1.0)
        return np.linalg.norm(p - (s + d * np.clip(t, 0.0, 1.0)[:, None]), axis=1)

    edges = np.minimum.reduce([to_edges(a, b), to_edges(b, c), to_edges(c, a)])
    n = np.cross(b - a, c - a)
    nn = np.einsum("ij,ij->i", n, n)
    h = np.einsum("ij,ij->i", p - a, n) / np.where(nn > 0, nn, 1.0)
    q = p - n * h[:, None]

    def inner_side(s, e):
        return np.einsum("ij,ij->i", np.cross(e - s, q - s), n) >= 0

    inside = (nn > 0) & inner_side(a, b) & inner_side(b, c) & inner_side(c, a)
    return np.where(inside, np.abs(h) * np.sqrt(nn), edges)


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
