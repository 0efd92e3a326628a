"""asbuilt from Python: geometric inspection for construction 3D printing.

Designs and signed cloud-to-mesh distances (C2M), the deviation suite (coverage, M3C2 along the
design's normals, the findings a crew acts on), recordings read back as `asbuilt report` reads
them, the command line's commands, and the cell's side of a running agent. Everything is
metres, in the design frame unless a name says otherwise; arrays are NumPy arrays.

    import asbuilt
    design = asbuilt.Design.load("part.stl", units="mm")
    result = design.c2m(points, max_distance=0.05)
    result["distance"]  # signed metres, NaN beyond max_distance
"""

from __future__ import annotations

import json
import os
import time
import tempfile
from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional

from ._asbuilt import Cell as _Cell, Design, SimulatedJob as _SimulatedJob, __version__
from ._asbuilt import read_recording_parts as _read_recording_parts
from ._asbuilt import inspect as _inspect
from ._asbuilt import run as _run
from ._asbuilt import suite
from .agent import Agent

__all__ = [
    "Agent",
    "Cell",
    "Design",
    "Recording",
    "Station",
    "SimulatedJob",
    "argv",
    "inspect",
    "read_recording",
    "run",
    "suite",
    "__version__",
]

#: Deviation flags (the `flags` array of `Design.c2m` and of a station's deviations).
NO_MATCH = 1
REJECTED = 2
OUT_OF_TOLERANCE = 4


def argv(**options: Any) -> List[str]:
    """Command-line flags from keywords: `max_distance=0.01` -> `--max-distance 0.01`,
    `png=True` -> `--png`, a list -> the flag repeated (or joined with commas where the command
    takes a list, as `method` and `scan_after` do); None and False are left out. Values are
    attached with `=` so that negative numbers stay values."""
    out: List[str] = []
    comma = {"method", "scan_after", "translation", "rotation_xyzw"}
    for key, value in options.items():
        if value is None or value is False:
            continue
        flag = "--" + key.replace("_", "-")
        if value is True:
            out.append(flag)
        elif isinstance(value, (list, tuple)):
            if key in comma:
                out.append(flag + "=" + ",".join(str(v) for v in value))
            else:
                out += [f"{flag}={v}" for v in value]
        else:
            out.append(f"{flag}={os.fspath(value) if hasattr(value, '__fspath__') else value}")
    return out


def run(*args: str) -> int:
    """Runs an `asbuilt` command in this process, as on the command line:
    `asbuilt.run("report", "job.mcap", "--out", "out/report")`. Returns its exit code."""
    return _run([os.fspath(a) if hasattr(a, "__fspath__") else str(a) for a in args])


def inspect(design, units: str, *, out=None, **options: Any) -> Dict[str, Any]:
    """`asbuilt inspect` in this process; returns report.json as a dict.

    Keywords are the command's flags, typed, with `_` for `-` (`stations=`, `scan=`,
    `translation=[x, y, z]`, `rotation_xyzw=[x, y, z, w]`, `tolerance=`, `max_distance=`,
    `method=["c2m", "coverage", "m3c2"]`, `limit=["width=4mm"]`, `layer_height=`,
    `printed_height=`, `png=True`, `ros2=BAG` with `cloud_topic=` and `frame=` for a ROS 2
    bag's clouds placed by its transform tree, ...); one left out takes the command's default. Outputs
    (deviations.ply, report.json, ...) go to `out`, a temporary folder when not given. The exit
    code (1 when out of tolerance) is the report's `assessment`; a refused value raises
    ValueError, an unknown keyword TypeError, a failure RuntimeError.
    """
    with tempfile.TemporaryDirectory(prefix="asbuilt-inspect-") as scratch:
        folder = os.fspath(out) if out is not None else scratch
        paths = {k: os.fspath(v) for k, v in options.items() if hasattr(v, "__fspath__")}
        _inspect(os.fspath(design), units, out=folder, **{**options, **paths})
        with open(os.path.join(folder, "report.json"), encoding="utf-8") as f:
            return json.load(f)


@dataclass
class Station:
    """One station of a recording, as `asbuilt report` reads it back.

    `scan_points` are the recorded points in the scanner frame ((N, 3) float32, chunk by chunk,
    `scan_chunk` the chunk of each); `deviations` holds the agent's inspection of them
    (`position`, design frame, `distance`, `triangle`, `feature`, `flags`, `chunk`): a chunk the
    agent could not inspect (no pose, over its limits) has no deviations.
    """

    job: int
    station: int
    name: str = ""
    layer: int = 0
    printed_height: float = float("nan")
    pose: Optional[Dict[str, Any]] = None
    scan_points: Any = None
    scan_chunk: Any = None
    deviations: Dict[str, Any] = field(default_factory=dict)
    report: Optional[Dict[str, Any]] = None
    findings: Optional[Dict[str, Any]] = None

    @property
    def design_points(self):
        """The inspected points in the design frame, (N, 3) float64."""
        return self.deviations.get("position")

    def __repr__(self) -> str:
        n = 0 if self.scan_points is None else len(self.scan_points)
        return f"Station(job={self.job}, station={self.station}, name={self.name!r}, points={n})"


@dataclass
class Recording:
    """A recording read back: `report` is report.json's content as `asbuilt report` writes it,
    `stations` each station's inputs and outputs."""

    path: str
    report: Dict[str, Any]
    stations: List[Station]


def read_recording(path, *, tolerance: Optional[float] = None,
                   max_distance: Optional[float] = None) -> Recording:
    """Reads a recording (the agent's recorder or `asbuilt pack`) with `asbuilt report`'s own
    code: the design attached to it, the agent's recorded settings, every station inspected
    again. `tolerance` and `max_distance` override the recorded ones, as the command's flags."""
    report, stations = _read_recording_parts(os.fspath(path), tolerance, max_distance)
    for s in stations:
        for key in ("pose", "report", "findings"):
            s[key] = _public(s.get(key))
    return Recording(os.fspath(path), report, [Station(**s) for s in stations])


def _public(value: Any) -> Any:
    """A message as a dict without its wire-format padding (`_reserved...` fields)."""
    if isinstance(value, dict):
        return {k: _public(v) for k, v in value.items() if not k.startswith("_")}
    if isinstance(value, list):
        return [_public(v) for v in value]
    return value


class Cell:
    """The cell's side of a running agent (its `services.prefix`), as a robot controller and a
    scanner driver talk to it over iceoryx2 shared memory.

        cell = asbuilt.Cell("asbuilt")
        cell.send_station(0, points, translation, rotation_xyzw, name="L008-S1", layer=7,
                          printed_height=0.16)
        for message in cell.receive(timeout=5.0):
            ...   # message["kind"] is "report", "findings", "correction" or "surface"

    `send_station` sends Begin, the pose, the points in chunks (the last flagged) and End, and
    returns the points sent; `points` are (N, 3) float32 in the scanner frame, the pose is
    what the robot reports in `pose_mode` ("design_scanner", "fixed" or "6dof"). `receive`
    returns the agent's reports, findings, corrections (advice for the layers still to
    print, when its `[corrections]` are on) and surface judgements (flatness, dimensions and
    plumb, when its `[tolerances]` name a standard) that arrived, waiting up to `timeout` seconds for
    the first. One thread only: the ports are not shared between threads.

    A report's `status` is one of `STATUS`; `Interrupted` means the agent stopped (or started
    again) while the station was sending: send it again with `attempt=` one more.
    `deliver_station` does that for you.
    """

    STATUS = ("Complete", "Incomplete", "TimedOut", "Partial", "Interrupted")

    def __init__(self, prefix: str, *, max_points_per_chunk: int = 16384, wait: float = 10.0):
        self._cell = _Cell(prefix, max_points_per_chunk=max_points_per_chunk, wait=wait)
        self._kept: List[Dict[str, Any]] = []

    def send_station(self, station: int, points, translation, rotation_xyzw, **options) -> int:
        return self._cell.send_station(station, points, translation, rotation_xyzw, **options)

    def send_applied(self, layer: int, **options) -> None:
        """Tells the agent what the printer applied to `layer` once it is printed: `z_offset`
        (metres), `flow` (factor), `path_offset` ((x, y) metres) and `advice_layer` (the layer
        of the advice followed, None without). The agent's next advice builds on what was
        applied; layers it is not told of are taken as printed as designed."""
        self._cell.send_applied(layer, **options)

    def send_pass(self, pass_: int, **options) -> None:
        """Opens a line profiler's pass (a station numbered `pass_`: `layer`,
        `printed_height`, `name`), or closes it with `end=True`, `chunks` and `points` sent."""
        self._cell.send_pass(pass_, **options)

    def send_mount_pose(self, time_ns: int, translation, rotation_xyzw, **options) -> None:
        """A robot pose of the profiler's mount at `time_ns` on the robot's clock
        (`T_base_mount`), with the calibration `mount_sensor_translation` and
        `mount_sensor_rotation_xyzw` (`T_mount_sensor`); `pass_`, `sequence`, `job`."""
        self._cell.send_mount_pose(time_ns, translation, rotation_xyzw, **options)

    def send_profiles(self, pass_: int, sequence: int, sensor_ns, counts, points,
                      **options) -> None:
        """Chunk `sequence` of a pass: up to 32 profiles taken at `sensor_ns` (the
        profiler's clock), `counts[i]` points each, their points one after the other in
        `points`, (N, 2) float32 metres along the line and along the view; `last=True` on the
        pass's last chunk."""
        self._cell.send_profiles(pass_, sequence, list(sensor_ns), list(counts), points,
                                 **options)

    def receive(self, timeout: float = 0.0) -> List[Dict[str, Any]]:
        kept, self._kept = self._kept, []
        return kept + [_public(m) for m in self._cell.receive(0.0 if kept else timeout)]

    def deliver_station(self, station: int, points, translation, rotation_xyzw, *,
                        attempts: int = 5, timeout: float = 60.0,
                        **options) -> Dict[str, Any]:
        """Sends a station and waits for its report; an attempt that does not end `Complete`
        (the agent was killed and started again, a chunk went missing) is sent again as the
        next attempt, up to `attempts`. Returns the last attempt's report, with the earlier
        ones under `"earlier"`. Other messages that arrive meanwhile are kept for `receive`."""
        job = options.get("job", 1)
        earlier: List[Dict[str, Any]] = []
        for attempt in range(1, attempts + 1):
            self.send_station(station, points, translation, rotation_xyzw, attempt=attempt,
                              **options)
            report = self._wait_for_report(job, station, attempt, timeout)
            if report is None:
                raise TimeoutError(f"station {station} attempt {attempt}: no report within "
                                   f"{timeout} s; is the agent running?")
            if self.STATUS[report["status"]] == "Complete" or attempt == attempts:
                report["earlier"] = earlier
                return report
            earlier.append(report)
        raise AssertionError("unreachable")

    def _wait_for_report(self, job: int, station: int, attempt: int, timeout: float):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for m in [_public(m) for m in self._cell.receive(0.2)]:
                mine = (m["kind"] == "report" and m["job"] == job and m["station"] == station
                        and max(m["attempt"], 1) == attempt)
                if mine:
                    return m
                # Reports come at least once: an agent resuming its job publishes its recorded
                # reports again; an earlier attempt's is not news.
                if m["kind"] == "report" and m["station"] == station and m["job"] == job:
                    continue
                self._kept.append(m)
        return None


class SimulatedJob(_SimulatedJob):
    """A simulated print job, as `asbuilt sim` runs it: `SimulatedJob(part="wall",
    scan_after=[8, 16], defect=["bulge:x=0,y=-0.5,z=0.3,radius=0.1,height=8mm"], seed=1)`.
    Keywords are `asbuilt sim`'s job flags, typed (`rate` is points per second or "max"); one
    left out takes `asbuilt sim`'s default. `stations()` is the robot's plan, `scan(i)` what
    the scanner sees at station i, `design` the part. `print_to(layers, correction)` prints
    the layers up to `layers` with an agent's advice applied (closing the loop); scans after
    it see them so."""

    def __new__(cls, **options: Any):
        return super().__new__(cls, **options)

    def run(self, cell: "Cell", *, findings: bool = False, wait: float = 60.0) -> Dict[str, Any]:
        """Runs the whole job through `cell` as `asbuilt sim` does (with
        `sensor="profiler"`, every layer a pass of poses and profiles); returns the `reports`
        and `findings` that came back, `points_sent` and `seconds`."""
        return super().run(cell._cell, findings=findings, wait=wait)

    def send(self, cell: "Cell", station: Dict[str, Any]) -> int:
        """Scans `station` (an entry of `stations()`) and sends it through `cell` as the robot
        cell does: Begin with its layer and printed height, the pose, the points in chunks, End.
        Returns the points sent."""
        scan = self.scan(station["index"])
        return cell.send_station(
            station["index"], scan["points"], station["translation"], station["rotation_xyzw"],
            job=self.job, name=station["name"], layer=station["printed"] - 1,
            printed_height=station["printed_height"], position_sigma=station["position_sigma"],
            pose_mode=station["pose_mode"], intensity=scan["intensity"], flags=scan["flags"])
