"""A fleet's recordings inspected again on Dask, into a Parquet dataset and a fleet page.

Each job (one recording, or the several files an agent wrote for one job: resumed after a stop,
or rotated into parts) is one Dask task that runs `asbuilt report`'s own code on it, with the
limits and standards given, holding no scan in memory (as `report` does). Its report.json
becomes rows:

- ``jobs``: one row per job (its verdict, counts, the share of its layers out of tolerance);
- ``stations``: one row per station, its statistics and verdict;
- ``findings``: one row per judged finding of every scan layer (width, shift, top, regions,
  missing areas), as report.json's ``assessment.scan_layers[].items`` gives them;
- ``layer_history``: one row per printed layer band and scan layer that measured it;
- ``errors``: one row per job that could not be read, with why.

Every row carries the job's metadata (file, job, start time, design, units, tolerance, limits,
standards). Tables are folders of Parquet files, one file per job, which pandas, DuckDB, Spark
and pyarrow read as one dataset: ``pandas.read_parquet("DIR/stations")``.

The same call runs on one laptop (a ``LocalCluster``, the default) or on an existing cluster
(``scheduler="tcp://host:8786"``, or a ``client=`` from dask-jobqueue or dask-kubernetes).
Recordings may be local paths, globs, folders or fsspec URLs (``s3://bucket/jobs/*.mcap`` where
s3fs is installed); a remote file is copied to the worker's temporary folder for its task.

Needs the ``archive`` extra: ``pip install "./tools/python[archive]"``.
"""

from __future__ import annotations

import argparse
import glob as _glob
import html
import io
import json
import math
import os
import re
import shutil
import socket
import sys
import tempfile
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Any, Dict, Iterable, List, Optional, Sequence

__all__ = ["Job", "ArchiveResult", "find_jobs", "inspect_job", "analyse", "main", "TABLES"]

#: The agent recorder's file names: job-{job}-{stamp}[-part{n}].mcap.
_AGENT_FILE = re.compile(r"^job-(\d+)-(\d+)(?:-part(\d+))?\.mcap$")


@dataclass
class Job:
    """One job's recordings, oldest first. `name` identifies it in every table."""

    name: str
    files: List[str]
    number: Optional[int] = None


def _is_url(s: str) -> bool:
    return "://" in s and not s.startswith("file://")


def _expand(source: str) -> List[str]:
    """The recordings a path, glob, folder or URL names, sorted."""
    if _is_url(source):
        import fsspec

        fs, path = fsspec.core.url_to_fs(source)
        if any(c in path for c in "*?["):
            found = fs.glob(path)
        elif fs.isdir(path):
            found = [p for p in fs.find(path) if p.endswith(".mcap")]
        else:
            found = [path]
        return sorted(fs.unstrip_protocol(p) for p in found)
    if source.startswith("file://"):
        source = source[len("file://"):]
    # Absolute, so that a worker started in another folder (or on another machine that mounts
    # the same path) finds the file.
    source = os.path.abspath(source)
    if any(c in source for c in "*?["):
        return sorted(_glob.glob(source, recursive=True))
    if os.path.isdir(source):
        return sorted(
            os.path.join(root, f)
            for root, _, files in os.walk(source)
            for f in files
            if f.endswith(".mcap")
        )
    return [source]


def _prints(files: List[str]) -> List[List[str]]:
    """The agent's files of one job (oldest first) split into prints, each from a first part."""
    prints: List[List[str]] = []
    for f in files:
        part = _AGENT_FILE.match(os.path.basename(f)).group(3)
        if not prints or part is None or int(part) == 1:
            prints.append([])
        prints[-1].append(f)
    return prints


def find_jobs(sources: Iterable[Any]) -> List[Job]:
    """The jobs `sources` name (paths, globs, folders, fsspec URLs). The agent recorder's files
    of one job in one folder go together, oldest first; any other file is a job of its own. A
    source that names nothing is a job whose task reports that as its error."""
    groups: Dict[Any, List[tuple]] = {}
    for source in sources:
        source = os.fspath(source) if hasattr(source, "__fspath__") else str(source)
        found = _expand(source)
        if not found:
            where = source if _is_url(source) else os.path.abspath(source)
            groups.setdefault(("missing", where), []).append(((0, 0), where))
        for f in found:
            m = _AGENT_FILE.match(os.path.basename(f))
            if m:
                key = ("agent", os.path.dirname(f), int(m.group(1)))
                order = (int(m.group(2)), int(m.group(3) or 1))
            else:
                key = ("file", f)
                order = (0, 0)
            if (order, f) not in groups.setdefault(key, []):
                groups[key].append((order, f))
    jobs = []
    for key, entries in groups.items():
        files = [f for _, f in sorted(entries)]
        if key[0] == "agent":
            # A print's files go from a first part to the parts after it; a job number used
            # again starts a new print (the recorder begins it with a first part).
            for print_files in _prints(files):
                stamp = _AGENT_FILE.match(os.path.basename(print_files[0])).group(2)
                jobs.append(Job(f"job-{key[2]}-{stamp}", print_files, key[2]))
        else:
            base = os.path.basename(files[0])
            jobs.append(Job(base[:-5] if base.endswith(".mcap") else base, files))
    return sorted(jobs, key=lambda j: (j.files[0], j.name))


@dataclass
class _Options:
    tolerance: Optional[float] = None
    max_distance: Optional[float] = None
    limits: Optional[List[str]] = None
    flatness: Optional[str] = None
    dimensions: Optional[str] = None
    decision_rule: Optional[str] = None


def _local_copies(files: Sequence[str], scratch: str) -> List[str]:
    """Local paths for `files`: remote ones are copied into `scratch`, streamed."""
    out = []
    for i, f in enumerate(files):
        if not _is_url(f):
            if not os.access(f, os.R_OK):
                raise FileNotFoundError(
                    f"{f} cannot be read on worker {socket.gethostname()} (pid {os.getpid()}): "
                    "a worker reads the recordings itself; give paths it can reach (a shared "
                    "folder, or a URL)")
            out.append(f)
            continue
        import fsspec

        target = os.path.join(scratch, f"{i:04d}-{os.path.basename(f)}")
        with fsspec.open(f, "rb") as src, open(target, "wb") as dst:
            shutil.copyfileobj(src, dst, 1 << 20)
        out.append(target)
    return out


def inspect_job(job: Job, options: Optional[Dict[str, Any]] = None) -> Dict[str, List[Dict]]:
    """One job through `asbuilt report`'s code: its rows, by table. A job that cannot be read
    gives one ``errors`` row instead. This is the Dask task; it never raises for bad input."""
    from ._asbuilt import report_job

    opts = _Options(**(options or {}))
    started = time.perf_counter()
    try:
        with tempfile.TemporaryDirectory(prefix="asbuilt-archive-") as scratch:
            paths = _local_copies(job.files, scratch)
            report, started_ns = report_job(
                paths,
                tolerance=opts.tolerance,
                max_distance=opts.max_distance,
                limits=opts.limits,
                flatness=opts.flatness,
                dimensions=opts.dimensions,
                decision_rule=opts.decision_rule,
                quiet=True,
            )
    except Exception as e:  # a damaged file, a missing one, a refused option: one error row
        return {"errors": [_error_row(job, e)]}
    rows = rows_of(job, report, started_ns, opts)
    rows["jobs"][0]["seconds"] = time.perf_counter() - started
    return rows


def _check(options: Dict[str, Any]) -> None:
    """Refuses a bad limit or standard once, before any task runs (else every job would be an
    error row): the native reader checks its options before it looks for a file."""
    from ._asbuilt import report_job

    try:
        report_job([], **options)
    except ValueError:
        raise
    except RuntimeError:
        pass  # the options passed; there was no recording to read


def _error_row(job: Job, e: BaseException) -> Dict[str, Any]:
    return {
        "job": job.name,
        "file": job.files[0],
        "files": len(job.files),
        "error": f"{type(e).__name__}: {e}",
    }


def _num(v: Any) -> Optional[float]:
    """A JSON number as a float; None for null (NaN in report.json)."""
    return None if v is None else float(v)


def _triple(v: Any, i: int) -> Optional[float]:
    return None if v is None else _num(v[i])


def rows_of(job: Job, report: Dict[str, Any], started_ns: Optional[int],
            opts: _Options) -> Dict[str, List[Dict]]:
    """The tables' rows for one job's report.json (as `asbuilt report` writes it)."""
    assessment = report.get("assessment") or {}
    params = report.get("parameters") or {}
    design = report.get("design") or {}
    flatness = report.get("flatness") or {}
    dimensions = report.get("dimensions") or {}
    meta = {
        "job": job.name,
        "job_number": job.number,
        "file": job.files[0],
        "files": len(job.files),
        "started": (None if started_ns is None
                    else datetime.fromtimestamp(started_ns / 1e9, tz=timezone.utc)),
        "design": design.get("path"),
        "units": design.get("units"),
        "tolerance_m": _num(params.get("tolerance_m")),
        "limits": json.dumps(assessment.get("limits"), sort_keys=True),
        "flatness_standard": flatness.get("standard") if isinstance(flatness, dict) else None,
        "dimensions_standard": (dimensions.get("standard")
                                if isinstance(dimensions, dict) else None),
        "decision_rule": (assessment.get("limits") or {}).get("decision_rule"),
    }
    verdicts = {s["id"]: s for s in assessment.get("stations", [])}
    stations = []
    for s in report.get("stations", []):
        v = verdicts.get(s["id"], {})
        stations.append({
            **meta,
            "station": s["id"],
            "verdict": v.get("verdict"),
            "reason": v.get("reason"),
            **{k: (int(s[k]) if k in _COUNTS else _num(s.get(k))) for k in _STATION_FIELDS},
        })
    findings = []
    scan_layers = assessment.get("scan_layers", [])
    for sl in scan_layers:
        for item in sl.get("items", []):
            layers = item.get("layers") or [None, None]
            z = item.get("z") or [None, None]
            findings.append({
                **meta,
                "scan_layer": sl.get("layer"),
                "printed_height": _num(sl.get("printed_height")),
                "scan_stations": sl.get("stations"),
                "scan_verdict": sl.get("verdict"),
                "label": item.get("label"),
                "kind": item.get("kind"),
                "verdict": item.get("verdict"),
                "value": _num(item.get("value")),
                "uncertainty": _num(item.get("uncertainty")),
                "limit": _num(item.get("limit")),
                "layer_first": layers[0],
                "layer_last": layers[1],
                "z_min": _num(z[0]),
                "z_max": _num(z[1]),
                "at_x": _triple(item.get("at"), 0),
                "at_y": _triple(item.get("at"), 1),
                "at_z": _triple(item.get("at"), 2),
                "since": item.get("since"),
                "change": item.get("change"),
                "text": item.get("text"),
            })
    history = []
    for band in assessment.get("layer_history", []):
        for scan in band.get("scans", []):
            history.append({
                **meta,
                "layer": band.get("layer"),
                "z_min": _num(band.get("z_min")),
                "z_max": _num(band.get("z_max")),
                "scan_layer": scan.get("scan_layer"),
                "printed_height": _num(scan.get("printed_height")),
                "samples": scan.get("samples"),
                "mean": _num(scan.get("mean")),
                "width": _num(scan.get("width")),
                "width_relative": _num(scan.get("width_relative")),
                "shift_x": _triple(scan.get("shift"), 0),
                "shift_y": _triple(scan.get("shift"), 1),
                "top": _num(scan.get("top")),
                "verdict": _band_verdict(scan_layers, scan.get("scan_layer"), band.get("layer")),
            })
    last = scan_layers[-1] if scan_layers else None
    # Each layer band as its latest reading judged it: a scanner's last scan layer reads every
    # layer, a line profiler's pass only those within its reach.
    latest = {}
    for h in history:
        if h["layer"] not in latest or (h["scan_layer"] or 0) >= (latest[h["layer"]]["scan_layer"] or 0):
            latest[h["layer"]] = h
    last_bands = list(latest.values())
    counts = (last or {}).get("counts") or {}
    overall = report.get("overall") or {}
    summary = assessment.get("summary") or []
    jobs = [{
        **meta,
        "verdict": assessment.get("verdict"),
        "summary": summary[0] if summary else None,
        "stations": len(stations),
        "points": int(overall.get("points", 0)),
        "scan_layers": len(scan_layers),
        "last_scan_layer": None if last is None else last.get("layer"),
        "findings_fail": int(counts.get("fail", 0)),
        "findings_warn": int(counts.get("warn", 0)),
        "findings_inconclusive": int(counts.get("inconclusive", 0)),
        **_standards_columns(flatness, dimensions),
        "layers_measured": len(last_bands),
        "layers_out_of_tolerance": sum(1 for h in last_bands if h["verdict"] == "fail"),
        "share_layers_out_of_tolerance": (
            sum(1 for h in last_bands if h["verdict"] == "fail") / len(last_bands)
            if last_bands else None),
        "warnings": len(report.get("warnings") or []),
        "seconds": None,
    }]
    return {"jobs": jobs, "stations": stations, "findings": findings, "layer_history": history}


def _standards_columns(flatness: Any, dimensions: Any) -> Dict[str, Any]:
    """The standards' verdicts, and what was not judged and why: `not_judged` is its own
    verdict, never a pass."""
    flatness = flatness if isinstance(flatness, dict) else {}
    dimensions = dimensions if isinstance(dimensions, dict) else {}
    not_judged = flatness.get("not_judged") or []
    return {
        "flatness_verdict": flatness.get("verdict"),
        "flatness_not_judged": len(not_judged) if flatness else None,
        "flatness_not_judged_reason": flatness.get("not_judged_reason"),
        "dimensions_verdict": dimensions.get("verdict"),
    }


def _band_verdict(scan_layers: List[Dict], scan_layer: Any, layer: Any) -> Optional[str]:
    """A band's verdict at a scan layer, as the report judged it (`scan_layers[].layers`: the
    worst verdict of what touches the band); None when that scan layer did not judge it."""
    for sl in scan_layers:
        if sl.get("layer") == scan_layer:
            for v in sl.get("layers", []):
                if v.get("layer") == layer:
                    return v.get("verdict")
    return None


_COUNTS = {"points", "valid", "rejected", "matched", "no_match", "within_tolerance",
           "above_tolerance", "below_tolerance"}
_STATION_FIELDS = ["points", "valid", "rejected", "matched", "no_match", "mean", "std", "rms",
                   "min", "max", "median_abs", "p95_abs", "within_tolerance", "above_tolerance",
                   "below_tolerance"]


def _schemas():
    import pyarrow as pa

    meta = [("job", pa.string()), ("job_number", pa.int64()), ("file", pa.string()),
            ("files", pa.int64()), ("started", pa.timestamp("ns", tz="UTC")),
            ("design", pa.string()), ("units", pa.string()), ("tolerance_m", pa.float64()),
            ("limits", pa.string()), ("flatness_standard", pa.string()),
            ("dimensions_standard", pa.string()), ("decision_rule", pa.string())]
    f64, i64, s = pa.float64(), pa.int64(), pa.string()
    station = [("station", s), ("verdict", s), ("reason", s)] + [
        (k, i64 if k in _COUNTS else f64) for k in _STATION_FIELDS]
    finding = [("scan_layer", i64), ("printed_height", f64), ("scan_stations", i64),
               ("scan_verdict", s), ("label", s), ("kind", s), ("verdict", s), ("value", f64),
               ("uncertainty", f64), ("limit", f64), ("layer_first", i64), ("layer_last", i64), ("z_min", f64),
               ("z_max", f64), ("at_x", f64), ("at_y", f64), ("at_z", f64), ("since", i64),
               ("change", s), ("text", s)]
    band = [("layer", i64), ("z_min", f64), ("z_max", f64), ("scan_layer", i64),
            ("printed_height", f64), ("samples", i64), ("mean", f64), ("width", f64),
            ("width_relative", f64), ("shift_x", f64), ("shift_y", f64), ("top", f64),
            ("verdict", s)]
    job = [("verdict", s), ("summary", s), ("stations", i64), ("points", i64),
           ("scan_layers", i64), ("last_scan_layer", i64), ("findings_fail", i64),
           ("findings_warn", i64), ("findings_inconclusive", i64), ("flatness_verdict", s),
           ("flatness_not_judged", i64), ("flatness_not_judged_reason", s),
           ("dimensions_verdict", s), ("layers_measured", i64), ("layers_out_of_tolerance", i64),
           ("share_layers_out_of_tolerance", f64), ("warnings", i64), ("seconds", f64)]
    error = [("job", s), ("file", s), ("files", i64), ("error", s)]
    return {
        "jobs": pa.schema(meta + job),
        "stations": pa.schema(meta + station),
        "findings": pa.schema(meta + finding),
        "layer_history": pa.schema(meta + band),
        "errors": pa.schema(error),
    }


#: The tables written, in this order.
TABLES = ("jobs", "stations", "findings", "layer_history", "errors")


def _part_name(job: Job) -> str:
    return re.sub(r"[^A-Za-z0-9._-]", "_", job.name) + ".parquet"


def _write_rows(out: str, job: Job, rows: Dict[str, List[Dict]], schemas) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    for table, items in rows.items():
        if not items:
            continue
        folder = os.path.join(out, table)
        os.makedirs(folder, exist_ok=True)
        pq.write_table(pa.Table.from_pylist(items, schema=schemas[table]),
                       os.path.join(folder, _part_name(job)))


@dataclass
class ArchiveResult:
    """What `analyse` wrote: the dataset's folder, the jobs read and those that failed."""

    out: str
    jobs: int
    errors: List[Dict[str, Any]] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def summary_html(self) -> str:
        return os.path.join(self.out, "summary.html")

    def table(self, name: str):
        """A table of the dataset as a pyarrow Table (empty with its schema if no rows)."""
        import pyarrow as pa
        import pyarrow.parquet as pq

        folder = os.path.join(self.out, name)
        if not os.path.isdir(folder) or not os.listdir(folder):
            return pa.Table.from_pylist([], schema=_schemas()[name])
        return pq.read_table(folder, schema=_schemas()[name])


class _Progress:
    """A progress bar on stderr (one line per job when stderr is not a terminal)."""

    def __init__(self, total: int, enabled: bool):
        self.total, self.done, self.errors = total, 0, 0
        self.enabled = enabled
        self.tty = enabled and sys.stderr.isatty()
        self.started = time.monotonic()

    def step(self, job: Job, error: bool) -> None:
        self.done += 1
        self.errors += int(error)
        if not self.enabled:
            return
        width = 30
        filled = int(width * self.done / max(self.total, 1))
        line = (f"archive [{'#' * filled}{'-' * (width - filled)}] {self.done}/{self.total} "
                f"jobs, {self.errors} error(s), {time.monotonic() - self.started:.1f} s")
        if self.tty:
            sys.stderr.write("\r" + line + ("\n" if self.done == self.total else ""))
        else:
            sys.stderr.write(f"{line}: {job.name}{' (error)' if error else ''}\n")
        sys.stderr.flush()


def analyse(sources: Iterable[Any], out: Any, *, workers: Optional[int] = None,
            scheduler: Optional[str] = None, client: Any = None,
            tolerance: Optional[float] = None, max_distance: Optional[float] = None,
            limits: Optional[Sequence[str]] = None, flatness: Optional[str] = None,
            dimensions: Optional[str] = None, decision_rule: Optional[str] = None,
            progress: bool = True) -> ArchiveResult:
    """Inspects every job of `sources` again on Dask and writes the Parquet dataset and
    summary.html into `out` (its tables are replaced).

    The scheduler is `client` (a ``distributed.Client``) when given, else the one at
    `scheduler` (``"tcp://host:8786"``), else a ``LocalCluster`` of `workers` processes (the
    machine's cores by default) that is closed afterwards. `tolerance`, `max_distance`,
    `limits` (``["width=4mm", "missing_area=10cm2@1-20"]``), `flatness` (``"din18202:6"``)
    `dimensions` (``"din18202"``) and `decision_rule` (``"iso14253-1"`` or ``"simple"``)
    override each recording's own, as `asbuilt report`'s flags do."""
    from distributed import Client, LocalCluster, as_completed

    if workers is not None and workers < 1:
        raise ValueError(f"workers must be at least 1, not {workers}")
    if sum(x is not None for x in (workers, scheduler, client)) > 1:
        raise ValueError("give at most one of workers, scheduler and client")
    out = os.fspath(out)
    jobs = find_jobs(sources)
    if not jobs:
        raise ValueError("no recordings: name files, globs, folders or URLs")
    options = _Options(tolerance, max_distance, list(limits) if limits else None, flatness,
                       dimensions, decision_rule).__dict__
    _check(options)
    schemas = _schemas()
    os.makedirs(out, exist_ok=True)
    for table in TABLES:
        shutil.rmtree(os.path.join(out, table), ignore_errors=True)
    owned = []
    if client is None:
        if scheduler is not None:
            client = Client(scheduler)
        else:
            cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1,
                                   threads_per_worker=1, processes=True,
                                   dashboard_address=":0")
            owned.append(cluster)
            client = Client(cluster)
        owned.insert(0, client)
    started = time.monotonic()
    bar = _Progress(len(jobs), progress)
    result = ArchiveResult(out, len(jobs))
    job_rows: List[Dict[str, Any]] = []
    try:
        futures = client.map(inspect_job, jobs, options=options, pure=False)
        by_key = {f.key: j for f, j in zip(futures, jobs)}
        for fut in as_completed(futures):
            job = by_key[fut.key]
            try:
                rows = fut.result()
            except Exception as e:  # the worker died under it: the job is an error row
                rows = {"errors": [_error_row(job, e)]}
            _write_rows(out, job, rows, schemas)
            result.errors += rows.get("errors", [])
            job_rows += rows.get("jobs", [])
            bar.step(job, bool(rows.get("errors")))
    finally:
        for o in owned:
            o.close()
    result.seconds = time.monotonic() - started
    with open(result.summary_html, "w", encoding="utf-8") as f:
        f.write(summary_page(job_rows, result.errors))
    return result


def _svg(fig) -> str:
    buf = io.StringIO()
    fig.savefig(buf, format="svg", bbox_inches="tight")
    text = buf.getvalue()
    return text[text.index("<svg"):]


_COLOURS = {"pass": "#2e7d32", "warn": "#f9a825", "fail": "#c62828", None: "#757575"}


def summary_page(jobs: List[Dict[str, Any]], errors: List[Dict[str, Any]]) -> str:
    """The fleet page: findings per job over time, the share of layers out of tolerance per
    job, each job's verdict, and the files that could not be read. One HTML file, the plots
    written into it (SVG), no network needed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    jobs = sorted(jobs, key=lambda j: (j["started"] or datetime.min.replace(tzinfo=timezone.utc),
                                       j["job"]))
    plots = []
    if jobs:
        fig, ax = plt.subplots(figsize=(8, 3.2))
        # By start time; by order when a job's start is not known (no station event).
        timed = all(j["started"] is not None for j in jobs)
        x = [j["started"] if timed else i for i, j in enumerate(jobs)]
        fails = [j["findings_fail"] for j in jobs]
        warns = [j["findings_warn"] for j in jobs]
        ax.plot(x, fails, "o-", color=_COLOURS["fail"], label="out of tolerance")
        ax.plot(x, warns, "s--", color=_COLOURS["warn"], label="to watch")
        ax.set_ylabel("findings at the last scan")
        if not timed:
            ax.set_xticks(range(len(jobs)), [j["job"] for j in jobs])
        ax.set_title("Findings per job over time")
        ax.legend(loc="upper left")
        if timed:
            import matplotlib.dates as mdates

            locator = mdates.AutoDateLocator()
            ax.xaxis.set_major_locator(locator)
            ax.xaxis.set_major_formatter(mdates.ConciseDateFormatter(locator))
        plots.append(_svg(fig))
        plt.close(fig)

        fig, ax = plt.subplots(figsize=(8, 0.4 * len(jobs) + 1.2))
        shares = [100 * (j["share_layers_out_of_tolerance"] or 0.0) for j in jobs]
        ax.barh([j["job"] for j in jobs], shares,
                color=[_COLOURS.get(j["verdict"], _COLOURS[None]) for j in jobs])
        ax.set_xlabel("% of the layers measured at the last scan out of tolerance")
        ax.set_xlim(0, max(100.0, max(shares) if shares else 0))
        ax.invert_yaxis()
        ax.set_title("Layers out of tolerance per job")
        plots.append(_svg(fig))
        plt.close(fig)

    def cell(v: Any) -> str:
        if isinstance(v, float):
            return "" if math.isnan(v) else f"{v:.3g}"
        if isinstance(v, datetime):
            return v.strftime("%Y-%m-%d %H:%M:%S UTC")
        return html.escape("" if v is None else str(v))

    rows = "".join(
        f"<tr><td>{cell(j['job'])}</td><td>{cell(j['started'])}</td>"
        f"<td style='background:{_COLOURS.get(j['verdict'], _COLOURS[None])};color:white'>"
        f"{cell(j['verdict'])}</td><td>{j['stations']}</td><td>{j['scan_layers']}</td>"
        f"<td>{j['findings_fail']}</td><td>{j['findings_warn']}</td>"
        f"<td>{cell(None if j['share_layers_out_of_tolerance'] is None else 100 * j['share_layers_out_of_tolerance'])}</td>"
        f"<td>{cell(j['design'])}</td><td>{cell(j['summary'])}</td></tr>"
        for j in jobs)
    err_rows = "".join(
        f"<tr><td>{cell(e['job'])}</td><td>{cell(e['file'])}</td><td>{cell(e['error'])}</td></tr>"
        for e in errors)
    verdicts = {v: sum(1 for j in jobs if j["verdict"] == v) for v in ("pass", "warn", "fail")}
    return f"""<!doctype html>
<html><head><meta charset="utf-8"><title>asbuilt fleet summary</title>
<style>body{{font-family:sans-serif;margin:2em;max-width:70em}}
table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:0.2em 0.5em;text-align:left}}
</style></head><body>
<h1>Fleet summary</h1>
<p>{len(jobs)} job(s) inspected again: {verdicts['pass']} pass, {verdicts['warn']} warn,
{verdicts['fail']} fail; {len(errors)} could not be read. The tables are beside this page
(jobs, stations, findings, layer_history, errors), one Parquet file per job.</p>
{''.join(f'<figure>{p}</figure>' for p in plots)}
<h2>Each job's verdict</h2>
<table><tr><th>job</th><th>started</th><th>verdict</th><th>stations</th><th>scan layers</th>
<th>out of tolerance</th><th>to watch</th><th>% layers out</th><th>design</th><th>summary</th></tr>
{rows}</table>
<h2>Could not be read</h2>
{'<table><tr><th>job</th><th>file</th><th>error</th></tr>' + err_rows + '</table>' if errors else '<p>None.</p>'}
</body></html>
"""


def main(argv: Optional[Sequence[str]] = None) -> int:
    """`python -m asbuilt archive FILES... --out DIR [--workers N | --scheduler ADDRESS]`."""
    p = argparse.ArgumentParser(
        prog="python -m asbuilt archive",
        description="Inspect a fleet's recordings again on Dask: a Parquet dataset (jobs, "
                    "stations, findings, layer_history, errors) and summary.html in OUT.")
    p.add_argument("recordings", nargs="+", metavar="RECORDING",
                   help="recordings: files, globs, folders or fsspec URLs (s3://...)")
    p.add_argument("--out", required=True, help="the dataset's folder (its tables are replaced)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, help="a local cluster of N worker processes "
                       "(default: the machine's cores)")
    where.add_argument("--scheduler", help="an existing Dask scheduler, tcp://HOST:8786")
    p.add_argument("--tolerance", type=float, help="metres, over each recording's own")
    p.add_argument("--max-distance", type=float, help="metres, over each recording's own")
    p.add_argument("--limit", action="append", metavar="KIND=VALUE[@LAYERS]",
                   help="a verdict limit, as `asbuilt report --limit`; repeatable")
    p.add_argument("--flatness", metavar="STANDARD:ROW", help="din18202:5|6|7 or aci117:A..D")
    p.add_argument("--dimensions", metavar="STANDARD", help="din18202")
    p.add_argument("--decision-rule", metavar="RULE",
                   help="iso14253-1 (guarded: inconclusive within U of a limit) or simple")
    args = p.parse_args(argv)
    if args.workers is not None and args.workers < 1:
        p.error("--workers must be at least 1")
    try:
        result = analyse(args.recordings, args.out, workers=args.workers,
                         scheduler=args.scheduler, tolerance=args.tolerance,
                         max_distance=args.max_distance, limits=args.limit,
                         flatness=args.flatness, dimensions=args.dimensions,
                         decision_rule=args.decision_rule)
    except ValueError as e:
        p.error(str(e))
    ok = result.jobs - len(result.errors)
    print(f"{ok} of {result.jobs} job(s) inspected in {result.seconds:.1f} s into {result.out}; "
          f"open {result.summary_html}")
    for e in result.errors:
        print(f"could not read {e['file']}: {e['error']}", file=sys.stderr)
    return 0 if ok > 0 else 2
