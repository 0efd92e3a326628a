"""The Python cell drives a real agent process through a small simulated job."""

import os
import time

import numpy as np
import pytest

import asbuilt


def agent_config(prefix, job):
    return {
        "design": {"path": "design.stl", "units": "m"},
        "inspect": {"tolerance": 0.005, "max_distance": 0.03},
        "services": {"prefix": prefix},
        "limits": {"max_points_per_chunk": 16384},
        "recorder": {"dir": "recording"},
        "findings": {"enabled": True, "layer_height": job.layer_height},
    }


def test_a_python_cell_gets_reports_and_findings(tmp_path):
    job = asbuilt.SimulatedJob(part="wall", scan_after=[8], stations=2, step_deg=0.15,
                               defect=["bulge:x=-0.5,y=-0.0867,z=0.08,radius=0.1,height=15mm"])
    job.design.write_stl(tmp_path / "design.stl")
    prefix = f"asbuilt-pytest-{os.getpid()}"
    with asbuilt.Agent(agent_config(prefix, job), str(tmp_path)) as agent:
        agent.wait_until_serving()
        cell = asbuilt.Cell(prefix, wait=30.0)
        sent = {}
        got = []
        for st in job.stations():
            scan = job.scan(st["index"])
            sent[st["index"]] = cell.send_station(
                st["index"], scan["points"], st["translation"], st["rotation_xyzw"],
                job=job.job, name=st["name"], layer=st["printed"] - 1,
                printed_height=st["printed_height"], position_sigma=st["position_sigma"],
                pose_mode=st["pose_mode"], intensity=scan["intensity"], flags=scan["flags"])
            assert sent[st["index"]] == len(scan["points"]) > 1000
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
    recordings = list((tmp_path / "recording").glob("*.mcap"))
    assert len(recordings) == 1
    rec = asbuilt.read_recording(recordings[0])
    assert [s.station for s in rec.stations] == [0, 1]
    assert [len(s.scan_points) for s in rec.stations] == [sent[0], sent[1]]


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
    with pytest.raises(ValueError, match="scan-after"):
        asbuilt.SimulatedJob(part="wall", scan_after=[99])
    with pytest.raises(ValueError, match="unexpected argument"):
        asbuilt.SimulatedJob(part="wall", colour="red")
