"""The Python cell drives a real agent process through a small simulated job."""

import os
import time

import numpy as np
import pytest

import asbuilt
from conftest import unit_cube


def agent_config(prefix, job):
    return {
        "design": {"path": "design.stl", "units": "m"},
        "inspect": {"tolerance": 0.005, "max_distance": 0.03},
        "services": {"prefix": prefix},
        "limits": {"max_points_per_chunk": 16384},
        # The tests' recordings take a few MB; what they check must not hang on the machine's
        # free space (the agent's default keeps 1 GB free for a print that runs for hours).
        "recorder": {"dir": "recording", "min_free_mb": 16},
        "findings": {"enabled": True, "layer_height": job.layer_height},
    }


def test_a_python_cell_gets_reports_and_findings(tmp_path, monkeypatch):
    job = asbuilt.SimulatedJob(part="wall", scan_after=[8], stations=2, step_deg=0.15,
                               defect=["bulge:x=-0.5,y=-0.0867,z=0.08,radius=0.1,height=15mm"])
    # The agent's folder given relative to the working directory, as a script would.
    monkeypatch.chdir(tmp_path)
    (tmp_path / "cell").mkdir()
    job.design.write_stl(tmp_path / "cell" / "design.stl")
    prefix = f"asbuilt-pytest-{os.getpid()}"
    with asbuilt.Agent(agent_config(prefix, job), "cell") as agent:
        agent.wait_until_serving()
        cell = asbuilt.Cell(prefix, wait=30.0)
        sent = {}
        got = []
        for st in job.stations():
            sent[st["index"]] = job.send(cell, st)
            assert sent[st["index"]] == len(job.scan(st["index"])["points"]) > 1000
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            got += cell.receive(timeout=1.0)
            kinds = [m["kind"] for m in got]
            if kinds.count("report") >= 2 and kinds.count("findings") >= 2:
                break
        assert agent.alive(), agent.log()
    reports = [m for m in got if m["kind"] == "report"]
    findings = [m for m in got if m["kind"] == "findings"]
    assert sorted(r["station"] for r in reports) == [0, 1], agent.log()
    for r in reports:
        assert r["points_received"] == sent[r["station"]]
        assert r["stats"]["count"] > 0.9 * r["points_received"]
        assert abs(r["stats"]["median_abs"]) < 0.005
    assert len(findings) >= 2
    # The bulge (15 mm out, 20 cm across) is found as an area out of tolerance.
    last = findings[-1]
    assert last["regions"], last
    # The agent recorded the job: the recording reads back with the same stations.
    recordings = list((tmp_path / "cell" / "recording").glob("*.mcap"))
    assert len(recordings) == 1
    rec = asbuilt.read_recording(recordings[0])
    assert [s.station for s in rec.stations] == [0, 1]
    assert [len(s.scan_points) for s in rec.stations] == [sent[0], sent[1]]


def test_a_station_sent_again_is_a_new_attempt_reported_once(tmp_path):
    job = asbuilt.SimulatedJob(part="wall", scan_after=[8], stations=1, step_deg=0.15)
    job.design.write_stl(tmp_path / "design.stl")
    prefix = f"asbuilt-pytest-attempt-{os.getpid()}"
    with asbuilt.Agent(agent_config(prefix, job), tmp_path) as agent:
        agent.wait_until_serving()
        cell = asbuilt.Cell(prefix, wait=30.0)
        st = job.stations()[0]
        scan = job.scan(0)
        args = (0, scan["points"], st["translation"], st["rotation_xyzw"])
        options = dict(job=job.job, name=st["name"], layer=st["printed"] - 1,
                       printed_height=st["printed_height"], pose_mode=st["pose_mode"])
        first = cell.deliver_station(*args, **options)
        assert asbuilt.Cell.STATUS[first["status"]] == "Complete", agent.log()
        assert first["attempt"] == 1 and first["earlier"] == []
        # The same station again, as the cell sends it after an interrupted report: a new
        # attempt, processed and reported on its own; the first is not reported again.
        cell.send_station(*args, attempt=2, **options)
        deadline = time.monotonic() + 60
        reports = []
        while time.monotonic() < deadline and not reports:
            reports = [m for m in cell.receive(timeout=1.0) if m["kind"] == "report"]
        assert [(r["station"], r["attempt"]) for r in reports] == [(0, 2)], agent.log()
        assert reports[0]["points_received"] == first["points_received"]
        assert reports[0]["stats"] == first["stats"]
        with pytest.raises(ValueError, match="attempt counts from 1"):
            cell.send_station(*args, attempt=0, **options)


def test_a_cell_without_an_agent_says_so():
    with pytest.raises(RuntimeError, match="no asbuilt-agent is serving"):
        asbuilt.Cell(f"asbuilt-pytest-none-{os.getpid()}", wait=0.2)


def test_send_station_checks_its_arrays(tmp_path):
    # The check comes before anything is sent, so no agent is needed past the ports: use a
    # cell on a fresh agent only when the arrays are right (covered above).
    job = asbuilt.SimulatedJob(part="wall", scan_after=[8], stations=1)
    assert job.layers == 49 and job.layer_height == pytest.approx(0.02)
    with pytest.raises(ValueError, match="no station 5"):
        job.scan(5)
    with pytest.raises(ValueError, match="scan after"):
        asbuilt.SimulatedJob(part="wall", scan_after=[99])
    with pytest.raises(ValueError, match="give fixed or 6dof|fixed or 6dof"):
        asbuilt.SimulatedJob(part="wall", pose_mode="design_scanner")
    with pytest.raises(TypeError, match="unexpected keyword argument"):
        asbuilt.SimulatedJob(part="wall", colour="red")


def _same(offline, live, path="findings"):
    """Counts equal, lengths equal; measures equal to 1e-9 relative (the agent sums a sample's
    cylinder over its own chunks, the suite over its own: the last bits may differ)."""
    if isinstance(live, dict):
        for k, v in live.items():
            if k not in ("kind", "job", "station", "layer", "version"):
                _same(offline[k], v, f"{path}.{k}")
    elif isinstance(live, (list, tuple)):
        assert len(offline) == len(live), f"{path}: {len(offline)} offline, {len(live)} live"
        for i, (a, b) in enumerate(zip(offline, live)):
            _same(a, b, f"{path}[{i}]")
    elif isinstance(live, float):
        assert (np.isnan(offline) and np.isnan(live)) or \
            abs(offline - live) <= 1e-9 * max(1.0, abs(live)), f"{path}: {offline} vs {live}"
    else:
        assert offline == live, f"{path}: {offline} vs {live}"


def test_the_offline_suite_on_a_recordings_scans_gives_the_agents_findings(tmp_path):
    # Height drift puts the top 14 mm above the printed height at the second scan layer, the
    # bulge a side 15 mm out: deviations beyond the coverage threshold, where an agent and an
    # offline run that looked for scan points differently would disagree.
    job = asbuilt.SimulatedJob(part="wall", scan_after=[8, 24], stations=2, step_deg=0.15,
                               defect=["bulge:x=-0.5,y=-0.0867,z=0.08,radius=0.1,height=15mm",
                                       "height-drift:from=10,per-layer=1mm"])
    job.design.write_stl(tmp_path / "design.stl")
    prefix = f"asbuilt-pytest-offline-{os.getpid()}"
    with asbuilt.Agent(agent_config(prefix, job), str(tmp_path)) as agent:
        agent.wait_until_serving()
        cell = asbuilt.Cell(prefix, wait=30.0)
        for st in job.stations():
            job.send(cell, st)
        deadline = time.monotonic() + 120
        got = []
        while time.monotonic() < deadline and sum(m["kind"] == "findings" for m in got) < 4:
            got += cell.receive(timeout=1.0)
        assert agent.alive(), agent.log()
    live = {}
    for m in got:
        if m["kind"] == "findings":
            live[m["layer"]] = m  # the last of a scan layer covers all its stations
    assert sorted(live) == [7, 23], got
    rec = asbuilt.read_recording(next((tmp_path / "recording").glob("*.mcap")))
    design = asbuilt.Design.load(tmp_path / "design.stl", units="m")
    for layer, findings in live.items():
        stations = [s for s in rec.stations if s.layer == layer]
        assert len(stations) == 2
        # The agent's fixed-orientation pose with no calibration: the scanner sits at the
        # pose's translation.
        inputs = [dict(points=s.design_points, origin=s.pose["translation"],
                       sigma=s.pose["position_sigma"]) for s in stations]
        offline = asbuilt.suite(design, inputs, methods=["coverage", "m3c2"], tolerance=0.005,
                                max_distance=0.03, layer_height=job.layer_height,
                                printed_height=stations[0].printed_height)["findings"]
        _same(offline, findings, f"layer {layer}")
    # The raised top was judged by the whole top, not by the few samples within 6 mm of it.
    assert live[23]["top_height_deviation"] > 0.010
    assert live[23]["top_samples"] > 0.5 * live[7]["top_samples"] > 100


def test_a_python_cell_closes_the_loop_with_the_agents_advice(tmp_path):
    """The agent advises after each scan layer; the printer applies it, says what it applied,
    and the drift it saw is taken back by the next scan."""
    job = asbuilt.SimulatedJob(part="wall", scan_after=[8, 16, 24], stations=4, step_deg=0.15,
                               defect=["height-drift:from=8,per-layer=0.5mm"])
    job.design.write_stl(tmp_path / "design.stl")
    prefix = f"asbuilt-pytest-loop-{os.getpid()}"
    config = agent_config(prefix, job)
    config["corrections"] = {"enabled": True, "bead_width": job.bead_width}
    tops = []
    with asbuilt.Agent(config, tmp_path) as agent:
        agent.wait_until_serving()
        cell = asbuilt.Cell(prefix, wait=30.0)
        advice = None
        for layers in (8, 16, 24):
            assert job.print_to(layers, advice) == 8
            for j in range(layers - 8, layers):
                cell.send_applied(j, advice_layer=advice and advice["layer"], **job.applied(j))
            stations = [st for st in job.stations() if st["printed"] == layers]
            for st in stations:
                job.send(cell, st)
            last = stations[-1]["index"]
            got, advice, deadline = [], None, time.monotonic() + 120
            while advice is None and time.monotonic() < deadline:
                got += cell.receive(timeout=1.0)
                advice = next((m for m in got if m["kind"] == "correction"
                               and m["station"] == last), None)
            assert advice is not None, agent.log()
            findings = [m for m in got if m["kind"] == "findings" and m["station"] == last]
            tops.append(findings[-1]["top_height_deviation"])
            assert advice["from_layer"] == layers
            # Bit 9, unanswered: the agent knew what was applied to every layer.
            assert advice["flags"] & (1 << 9) == 0, advice
    # Open loop the top would be 4 mm high after 16 layers and 8 mm after 24: the advice after
    # 16 takes it back.
    assert tops[1] > 0.0025, tops
    assert abs(tops[2]) < 0.002, tops


def test_a_python_cell_sends_a_line_profilers_pass(tmp_path):
    """A pass over the top of a 1 m cube: the mount 0.1 m above it moving along +x at 0.2 m/s,
    looking straight down, its line across; poses every 4 ms on the robot's clock, profiles of
    11 points every 0.5 ms on the profiler's, 1 ms behind. Every profile is placed on the top."""
    v, t = unit_cube()
    asbuilt.Design.from_arrays(v - 0.5, t).write_stl(tmp_path / "design.stl")
    prefix = f"asbuilt-pytest-profiler-{os.getpid()}"
    config = {
        "design": {"path": "design.stl", "units": "m"},
        "inspect": {"tolerance": 0.005, "max_distance": 0.03},
        "services": {"prefix": prefix},
        "profiler": {"clock_offset_ns": 1_000_000},
    }
    t0, offset = 1_000_000_000, 1_000_000
    # Sensor x (the line) along world y, y (the plane's normal) along x, z (the view) down:
    # the rotation (x, y, z) -> (y, x, -z), as a quaternion (scalar last).
    down = [2 ** -0.5, 2 ** -0.5, 0.0, 0.0]
    with asbuilt.Agent(config, tmp_path) as agent:
        agent.wait_until_serving()
        cell = asbuilt.Cell(prefix, max_points_per_chunk=65536, wait=30.0)
        cell.send_pass(3, layer=3)
        pose = 0
        line = np.stack([np.linspace(-0.05, 0.05, 11), np.full(11, 0.1)], axis=1)
        chunks = 20
        for c in range(chunks):
            js = range(c * 8, (c + 1) * 8)
            # The poses up to this chunk's last profile go first.
            while t0 + pose * 4_000_000 <= t0 + js[-1] * 500_000:
                t = t0 + pose * 4_000_000
                x = -0.4 + 0.2 * (t - t0) * 1e-9
                cell.send_mount_pose(t, [x, 0.0, 0.6], down, pass_=3, sequence=pose)
                pose += 1
            sensor_ns = [t0 + j * 500_000 - offset for j in js]
            cell.send_profiles(3, c, sensor_ns, [11] * 8,
                               np.tile(line, (8, 1)).astype(np.float32), last=c == chunks - 1)
        t = t0 + pose * 4_000_000
        cell.send_mount_pose(t, [-0.4 + 0.2 * (t - t0) * 1e-9, 0.0, 0.6], down, pass_=3,
                             sequence=pose)
        cell.send_pass(3, end=True, layer=3, chunks=chunks, points=chunks * 8 * 11)
        got = []
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not any(m["kind"] == "report" for m in got):
            got += cell.receive(timeout=1.0)
        assert agent.alive(), agent.log()
    reports = [m for m in got if m["kind"] == "report"]
    assert len(reports) == 1, agent.log()
    r = reports[0]
    assert asbuilt.Cell.STATUS[r["status"]] == "Complete", r
    assert r["points_received"] == r["stats"]["count"] == chunks * 8 * 11
    assert r["stats"]["median_abs"] < 1e-6
    with pytest.raises(ValueError, match="at most 32"):
        cell.send_profiles(3, 99, list(range(33)), [0] * 33, np.zeros((0, 2), np.float32))


def test_a_simulated_profiler_job_runs_through_a_python_cell(tmp_path):
    """`SimulatedJob(sensor="profiler")`: the column's first layers, each a pass of the
    simulated profiler (a coarse line), every profile placed and every layer judged."""
    job = asbuilt.SimulatedJob(part="column", sensor="profiler", layers=3, profile_points=32)
    job.design.write_stl(tmp_path / "design.stl")
    prefix = f"asbuilt-pytest-simprofiler-{os.getpid()}"
    config = agent_config(prefix, job)
    config["limits"]["max_points_per_chunk"] = 65536
    del config["recorder"]
    with asbuilt.Agent(config, tmp_path) as agent:
        agent.wait_until_serving()
        cell = asbuilt.Cell(prefix, max_points_per_chunk=65536, wait=30.0)
        out = job.run(cell, findings=True, wait=60.0)
        assert agent.alive(), agent.log()
    assert [r["station"] for r in out["reports"]] == [0, 1, 2], agent.log()
    for r in out["reports"]:
        assert asbuilt.Cell.STATUS[r["status"]] == "Complete"
        assert r["rejected"]["without_pose"] == 0
        assert r["stats"]["median_abs"] < 0.5e-3
    assert len(out["findings"]) == 3
