"""Shared fixtures: the repository's real data (the Stanford bunny beside the repository, as
the Rust tests use it). The reader for the PLY files asbuilt writes is in ply_reader.py."""

import os
import pathlib

import numpy as np
import pytest

REPO = pathlib.Path(__file__).resolve().parents[3]
DATA = REPO.parent / "shared" / "data"
BUNNY = DATA / "stanford-bunny" / "bun_zipper.ply"
BUNNY_STATIONS = REPO / "tools" / "examples" / "bunny" / "stations.toml"

@pytest.fixture(scope="session")
def bunny_path():
    if not BUNNY.exists():
        pytest.fail(f"{BUNNY} not found: the tests expect ../shared/data next to the repository")
    return BUNNY


@pytest.fixture(scope="session")
def bunny(bunny_path):
    import asbuilt

    return asbuilt.Design.load(bunny_path, units="m")


@pytest.fixture(scope="session")
def bunny_recording(tmp_path_factory, bunny_path):
    """The ten bunny stations packed into a recording with `asbuilt pack`."""
    import asbuilt

    out = tmp_path_factory.mktemp("recording") / "bunny.mcap"
    code = asbuilt.run("pack", "--stations", BUNNY_STATIONS, "--design", bunny_path,
                       "--units", "m", "--out", out)
    assert code == 0
    return out


def unit_cube():
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0],
                  [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], dtype=float)
    t = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4],
                  [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]])
    return v, t


os.environ.setdefault("RUST_BACKTRACE", "1")
