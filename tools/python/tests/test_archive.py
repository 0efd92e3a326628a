"""asbuilt.archive: a fleet's recordings inspected again on a 2-worker LocalCluster, into
Parquet rows that equal `asbuilt report` on each file, with a damaged file as an error row."""

import json
import math
import os
import shutil
import subprocess
import sys
import time

import pytest

import asbuilt

archive = pytest.importorskip("asbuilt.archive", reason="the archive extra is not installed")

from test_cell import agent_config  # noqa: E402  (the agent settings of the cell tests)

WALL_DEFECTS = [
    ["bulge:x=-0.5,y=-0.0867,z=0.08,radius=0.1,height=15mm"],
    [],
    ["over-extrusion:layers=2-4,width=12mm"],
]


def simulated_jobs(folder, prefix):
    """Three short wall jobs (2 stations after 8 layers) recorded by one agent,
    one recording each."""
    jobs = [asbuilt.SimulatedJob(part="wall", scan_after=[8], stations=2, step_deg=0.15,
                                 defect=d, job=n + 1, seed=n + 1)
            for n, d in enumerate(WALL_DEFECTS)]
    (folder / "cell").mkdir()
    jobs[0].design.write_stl(folder / "cell" / "design.stl")
    with asbuilt.Agent(agent_config(prefix, jobs[0]), folder / "cell") as agent:
        agent.wait_until_serving()
        cell = asbuilt.Cell(prefix, wait=30.0)
        for job in jobs:
            for st in job.stations():
                scan = job.scan(st["index"])
                report = cell.deliver_station(
                    st["index"], scan["points"], st["translation"], st["rotation_xyzw"],
                    job=job.job, name=st["name"], layer=st["printed"] - 1,
                    printed_height=st["printed_height"], position_sigma=st["position_sigma"],
                    pose_mode=st["pose_mode"], intensity=scan["intensity"], flags=scan["flags"])
                assert cell.STATUS[report["status"]] == "Complete", agent.log()
        # The last findings are on disk before the agent stops.
        time.sleep(1.0)
        assert agent.alive(), agent.log()
    return sorted((folder / "cell" / "recording").glob("job-*.mcap"))


@pytest.fixture(scope="module")
def fleet(tmp_path_factory, bunny_recording, bunny_path):
    """Six recordings: three simulated jobs, the packed bunny and a pack of three of its
    stations, and a damaged file."""
    folder = tmp_path_factory.mktemp("fleet")
    sims = simulated_jobs(folder, f"asbuilt-pytest-archive-{os.getpid()}")
    assert len(sims) == 3, sims
    files = list(sims)
    files.append(shutil.copy(bunny_recording, folder / "bunny.mcap"))
    stations = (folder / "three.toml")
    from conftest import BUNNY_STATIONS
    text = BUNNY_STATIONS.read_text()
    blocks = text.split("[[station]]")
    scans_dir = BUNNY_STATIONS.parent
    three = "".join("[[station]]" + b for b in blocks[1:4])
    stations.write_text(three.replace('scan = "', f'scan = "{scans_dir}/'))
    assert asbuilt.run("pack", "--stations", stations, "--design", bunny_path, "--units", "m",
                       "--out", folder / "bunny-three.mcap") == 0
    files.append(folder / "bunny-three.mcap")
    damaged = folder / "damaged.mcap"
    damaged.write_bytes(b"\x89MCAP0\r\n" + b"\0" * 4096)
    files.append(damaged)
    return folder, [str(f) for f in files]


def report_of(files, out):
    assert asbuilt.run("report", *files, "--out", out) in (0, 1)
    with open(os.path.join(out, "report.json"), encoding="utf-8") as f:
        return json.load(f)


def same(a, b):
    if isinstance(b, float) and math.isnan(b):
        return a is None or math.isnan(a)
    if b is None:
        return a is None or (isinstance(a, float) and math.isnan(a))
    return a == b


def test_a_fleet_on_a_two_worker_cluster_equals_report_on_each_file(tmp_path, fleet):
    folder, files = fleet
    out = tmp_path / "dataset"
    result = archive.analyse(files, out, workers=2)
    assert result.jobs == 6
    # The damaged file is an error row, and the rest went on.
    assert [e["file"] for e in result.errors] == [files[-1]]
    errors = result.table("errors").to_pylist()
    assert len(errors) == 1 and "damaged.mcap" in errors[0]["error"]

    stations = result.table("stations").to_pylist()
    findings = result.table("findings").to_pylist()
    history = result.table("layer_history").to_pylist()
    jobs = {j["file"]: j for j in result.table("jobs").to_pylist()}
    assert len(jobs) == 5
    for i, f in enumerate(files[:-1]):
        expected = report_of([f], str(tmp_path / f"report-{i}"))
        job = jobs[f]
        assert job["verdict"] == expected["assessment"]["verdict"]
        assert job["design"] == expected["design"]["path"]
        assert job["units"] == expected["design"]["units"]
        assert job["tolerance_m"] == expected["parameters"]["tolerance_m"]
        assert job["started"] is not None
        mine = [s for s in stations if s["job"] == job["job"]]
        assert [s["station"] for s in mine] == [s["id"] for s in expected["stations"]]
        verdicts = {v["id"]: v for v in expected["assessment"]["stations"]}
        for row, section in zip(mine, expected["stations"]):
            for key in ("points", "valid", "rejected", "matched", "no_match", "mean", "std",
                        "rms", "min", "max", "median_abs", "p95_abs", "within_tolerance"):
                assert same(row[key], section[key]), (f, key, row[key], section[key])
            assert row["verdict"] == verdicts[section["id"]]["verdict"]
            assert row["reason"] == verdicts[section["id"]]["reason"]
        assert job["decision_rule"] == expected["assessment"]["limits"]["decision_rule"]
        items = [(sl["layer"], it["label"], it["kind"], it["verdict"], it["value"],
                  it["uncertainty"], it["text"])
                 for sl in expected["assessment"]["scan_layers"] for it in sl["items"]]
        got = [(r["scan_layer"], r["label"], r["kind"], r["verdict"], r["value"],
                r["uncertainty"], r["text"])
               for r in findings if r["job"] == job["job"]]
        assert got == items, f
        bands = sum(len(b["scans"]) for b in expected["assessment"]["layer_history"])
        mine = [h for h in history if h["job"] == job["job"]]
        assert len(mine) == bands
        judged = {(sl["layer"], v["layer"]): v["verdict"]
                  for sl in expected["assessment"]["scan_layers"] for v in sl["layers"]}
        assert [h["verdict"] for h in mine] == [judged.get((h["scan_layer"], h["layer"]))
                                                 for h in mine]
    # The simulated jobs drew findings: the bulge is an excess, the over-extrusion of layers
    # 2-4 is their width, and the wall printed as designed has neither. (Two stations leave a
    # patch of its long faces unseen, which coverage calls missing in every job alike.)
    sims = [jobs[f] for f in files[:3]]
    assert all(j["scan_layers"] == 1 for j in sims)
    assert [j["job_number"] for j in sims] == [1, 2, 3]
    kinds = [{(r["kind"], r["layer_first"]) for r in findings
              if r["job"] == j["job"] and r["verdict"] == "fail"} for j in sims]
    assert any(k == "excess" for k, _ in kinds[0]) and sims[0]["verdict"] == "fail"
    assert {("width", 2), ("width", 3), ("width", 4)} <= kinds[2]
    assert not any(k in ("excess", "width", "deficit") for k, _ in kinds[1]), kinds[1]
    assert sims[2]["layers_out_of_tolerance"] >= 3
    assert len([h for h in history if h["job"] == sims[0]["job"]]) == 8
    page = (out / "summary.html").read_text()
    assert page.count("<svg") == 2 and "damaged.mcap" in page
    for j in jobs.values():
        assert j["job"] in page


def test_the_command_line_archives_a_glob_with_one_worker(tmp_path, fleet):
    folder, files = fleet
    out = tmp_path / "cli"
    run = subprocess.run([sys.executable, "-m", "asbuilt", "archive", str(folder / "bunny*.mcap"),
                          "--out", str(out), "--workers", "1", "--limit", "surface=2mm",
                          "--flatness", "din18202:6", "--decision-rule", "simple"],
                         capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    assert "2 of 2 job(s) inspected" in run.stdout
    assert "archive [" in run.stderr
    import pyarrow.parquet as pq

    jobs = pq.read_table(out / "jobs").to_pylist()
    assert sorted(j["job"] for j in jobs) == ["bunny", "bunny-three"]
    assert all(json.loads(j["limits"])["surface_m"] == 0.002 for j in jobs)
    # The bunny has no planar face: its flatness is not judged, never a pass, and says why.
    assert all(j["decision_rule"] == "simple" for j in jobs)
    assert all(j["flatness_verdict"] == "not_judged" and j["flatness_not_judged_reason"]
               for j in jobs), jobs
    # A bad limit is refused once, before any job runs.
    bad = subprocess.run([sys.executable, "-m", "asbuilt", "archive", files[3], "--out",
                          str(out), "--workers", "1", "--limit", "wobble=3mm"],
                         capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert bad.returncode == 2 and "wobble" in bad.stderr, bad.stderr


def test_an_agents_files_of_one_print_go_together(tmp_path):
    """A print's files run from a first part through the parts after it (a full file, an agent
    that resumed it); job 1 used again for a later print starts at a first part again."""
    for name in ["job-1-100.mcap", "job-1-100-part2.mcap", "job-1-250-part3.mcap",
                 "job-1-400.mcap", "job-2-300.mcap", "other.mcap", "notes.txt"]:
        (tmp_path / name).write_bytes(b"")
    jobs = archive.find_jobs([tmp_path])
    assert [(j.name, [os.path.basename(f) for f in j.files], j.number) for j in jobs] == [
        ("job-1-100", ["job-1-100.mcap", "job-1-100-part2.mcap", "job-1-250-part3.mcap"], 1),
        ("job-1-400", ["job-1-400.mcap"], 1),
        ("job-2-300", ["job-2-300.mcap"], 2),
        ("other", ["other.mcap"], None),
    ]
    # A glob and a file named twice give the same jobs once.
    again = archive.find_jobs([str(tmp_path / "job-2-*.mcap"), tmp_path / "job-2-300.mcap"])
    assert [j.name for j in again] == ["job-2-300"]


def test_a_recording_behind_an_fsspec_url_is_copied_for_its_task(fleet):
    """The task's remote path (as for s3://), in this process: fsspec's memory filesystem
    holds a recording; the task copies it, reads it, and gives report's rows."""
    import fsspec

    folder, files = fleet
    fs = fsspec.filesystem("memory")
    with open(files[3], "rb") as src:
        fs.pipe("/fleet/bunny.mcap", src.read())
    fs.pipe("/fleet/damaged.mcap", b"\x89MCAP0\r\n" + b"\0" * 64)
    jobs = archive.find_jobs(["memory://fleet/*.mcap"])
    assert [(j.name, j.files) for j in jobs] == [
        ("bunny", ["memory:///fleet/bunny.mcap"]), ("damaged", ["memory:///fleet/damaged.mcap"])]
    rows = archive.inspect_job(jobs[0])
    local = archive.inspect_job(archive.Job("bunny", [files[3]]))
    for table in ("stations", "findings", "layer_history"):
        strip = lambda rs: [{k: v for k, v in r.items() if k != "file"} for r in rs]  # noqa: E731
        assert strip(rows[table]) == strip(local[table])
    assert rows["jobs"][0]["file"] == "memory:///fleet/bunny.mcap"
    assert "errors" in archive.inspect_job(jobs[1])


def test_a_scheduler_and_workers_started_elsewhere_read_relative_paths(fleet, tmp_path):
    """The archive on a real cluster: a scheduler and a worker started as processes of their
    own in another folder, and the recordings named relative to where the archive runs. The
    paths go to the workers absolute, so every job is read; a path no worker can read is an
    error row that says so."""
    folder, files = fleet
    elsewhere = tmp_path / "workers"
    elsewhere.mkdir()
    info = tmp_path / "scheduler.json"
    python = [sys.executable, "-m"]
    scheduler = subprocess.Popen(
        python + ["distributed.cli.dask_scheduler", "--port", "0", "--dashboard-address", ":0",
                  "--scheduler-file", str(info)],
        cwd=elsewhere, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    worker = None
    try:
        deadline = time.monotonic() + 60
        while not info.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        worker = subprocess.Popen(
            python + ["distributed.cli.dask_worker", "--scheduler-file", str(info),
                      "--nworkers", "1", "--nthreads", "1", "--dashboard-address", ":0"],
            cwd=elsewhere, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        address = json.loads(info.read_text())["address"]
        good = [os.path.relpath(f, folder) for f in files[:2]]
        out = tmp_path / "fleet"
        run = subprocess.run(
            [sys.executable, "-m", "asbuilt", "archive", *good, "gone.mcap", "--out", str(out),
             "--scheduler", address],
            capture_output=True, text=True, timeout=600, cwd=folder)
        assert run.returncode == 0, run.stderr
        import pyarrow.parquet as pq

        errors = pq.read_table(out / "errors").to_pylist()
        assert [os.path.basename(e["file"]) for e in errors] == ["gone.mcap"], errors
        assert os.path.isabs(errors[0]["file"])
        jobs = pq.read_table(out / "jobs").to_pylist()
        assert len(jobs) == 2, (jobs, run.stderr)
    finally:
        for p in (worker, scheduler):
            if p is not None:
                p.terminate()
                p.wait(timeout=30)


def test_a_path_a_worker_cannot_read_is_an_error_row_that_says_so(tmp_path):
    row = archive.inspect_job(archive.Job("lost", [str(tmp_path / "lost.mcap")]))
    assert list(row) == ["errors"]
    assert "cannot be read on worker" in row["errors"][0]["error"], row


def test_each_layer_counts_by_its_latest_reading():
    """A line profiler's passes each read only the layers within reach: the job's share of
    layers out of tolerance takes each layer band's latest reading, not the last pass's bands
    alone. Layer 1 failed when pass 3 read it; the last pass (5) read layers 4 and 5 only."""
    from asbuilt.archive import Job, _Options, rows_of

    reads = {3: [0, 1, 2, 3], 5: [4, 5]}
    report = {"assessment": {
        "scan_layers": [{"layer": s, "layers": [
            {"layer": b, "verdict": "fail" if (s, b) == (3, 1) else "pass"} for b in bands]}
            for s, bands in reads.items()],
        "layer_history": [{"layer": b, "scans": [{"scan_layer": s} for s in reads if b in reads[s]]}
                          for b in range(6)],
    }}
    jobs = rows_of(Job("j", ["j.mcap"], 1), report, None, _Options())["jobs"]
    assert (jobs[0]["layers_measured"], jobs[0]["layers_out_of_tolerance"]) == (6, 1)
    assert jobs[0]["share_layers_out_of_tolerance"] == 1 / 6
