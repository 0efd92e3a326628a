"""Print a wall layer by layer with the simulated cell, scan it between layers through a real
asbuilt agent, and react to what the agent finds.

    pip install ./tools/python
    python tools/python/examples/print_wall.py [--out out/print_wall] [--prefix asbuilt]

Without --prefix the script starts its own agent (this package's `asbuilt agent`) in a child
process; with it, it talks to an agent already serving that prefix. This is the loop a COMPAS
robot script runs between layers: print, move the scanner to its stations, send each scan with
the robot's pose, read the findings and the agent's advice, decide, and print the next layers
with the advice applied (the agent's [corrections] are on; --open-loop leaves them unapplied).
"""

import argparse
import os
import sys

import asbuilt


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="out/print_wall", help="folder for the agent and recording")
    p.add_argument("--prefix", help="services prefix of a running agent (default: start one)")
    p.add_argument("--scan-every", type=int, default=8, help="layers between scans")
    p.add_argument("--step-deg", type=float, default=0.1, help="scanner step, degrees")
    p.add_argument("--open-loop", action="store_true",
                   help="print as designed whatever the agent advises")
    args = p.parse_args()

    # The wall of the source study with an over-extruded band, a bulge and a height drift,
    # scanned every `scan_every` layers from four stations.
    scan_after = list(range(args.scan_every, 33, args.scan_every))
    job = asbuilt.SimulatedJob(
        part="wall", scan_after=scan_after, stations=4, step_deg=args.step_deg,
        defect=["over-extrusion:layers=2-4,width=12mm",
                "bulge:x=-0.5,y=-0.0867,z=0.25,radius=0.1,height=15mm",
                "height-drift:from=8,per-layer=0.5mm"])
    os.makedirs(args.out, exist_ok=True)
    agent = None
    prefix = args.prefix
    if prefix is None:
        prefix = f"asbuilt-example-{os.getpid()}"
        job.design.write_stl(os.path.join(args.out, "design.stl"))
        agent = asbuilt.Agent({
            "design": {"path": "design.stl", "units": "m"},
            "inspect": {"tolerance": 0.005, "max_distance": 0.03},
            "services": {"prefix": prefix},
            "recorder": {"dir": "recording"},
            "findings": {"enabled": True, "layer_height": job.layer_height},
            "corrections": {"enabled": True, "bead_width": job.bead_width},
        }, args.out).start()
        agent.wait_until_serving()
        print(f"agent up: {agent.config_path}, log {agent.log_path}")
    try:
        return print_and_inspect(job, asbuilt.Cell(prefix, wait=30.0), not args.open_loop)
    finally:
        if agent is not None:
            agent.stop()
            print(f"agent stopped; recording in {os.path.join(args.out, 'recording')}")


def print_and_inspect(job, cell, closed_loop) -> int:
    plan = job.stations()
    printed = 0
    worst = 0
    advice = None
    for layers in sorted({st["printed"] for st in plan}):
        # The printer applies the latest advice from the next layer it prints.
        job.print_to(layers, advice if closed_loop else None)
        print(f"printed layers {printed + 1}–{layers} of {job.layers}"
              + (f" with the advice from layer {advice['from_layer'] + 1}" if advice and closed_loop
                 else ""))
        printed = layers
        print(f"scanning after layer {printed}")
        stations = [s for s in plan if s["printed"] == layers]
        for st in stations:
            job.send(cell, st)
            report = wait_for(cell, "report", st["index"])
            s = report["stats"]
            print(f"  {st['name']}: {report['points_received']} points, median |d| "
                  f"{s['median_abs'] * 1e3:.2f} mm, p95 {s['p95_abs'] * 1e3:.2f} mm")
        # The findings after a scan layer's last station cover all its stations.
        findings = wait_for(cell, "findings", stations[-1]["index"])
        worst = max(worst, react(findings))
        # The advice follows the findings: for the layers still to print.
        advice = wait_for(cell, "correction", stations[-1]["index"])
        print(f"  advice: z {advice['z_first'] * 1e3:+.2f} mm a layer for "
              f"{advice['first_layers']} layers, then {advice['z_then'] * 1e3:+.2f}; flow "
              f"×{advice['flow']:.3f}; path ({advice['path_offset'][0] * 1e3:+.1f}, "
              f"{advice['path_offset'][1] * 1e3:+.1f}) mm")
    return 1 if worst >= 2 else 0


def wait_for(cell, kind, station, timeout=120.0):
    """The agent's `kind` message ("report", "findings" or "correction") for `station`."""
    import time

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for m in cell.receive(timeout=1.0):
            wait_for.seen.append(m)
        for m in wait_for.seen:
            if m["kind"] == kind and m["station"] == station:
                wait_for.seen.remove(m)
                return m
    raise TimeoutError(f"no {kind} for station {station} within {timeout} s")


wait_for.seen = []


def react(f) -> int:
    """What the crew does about a scan layer's findings: 0 go on, 1 adjust, 2 stop."""
    tol = f["tolerance"]
    level = 0
    for row in f["layers"]:
        width = row.get("width_deviation")
        if width is not None and abs(width) > tol:
            print(f"  layer {row['layer']}: width off by {width * 1e3:+.1f} mm: "
                  f"{'reduce' if width > 0 else 'raise'} the flow")
            level = max(level, 1)
    for r in f["regions"]:
        x, y, z = r["centroid"]
        print(f"  area out of tolerance at ({x:.2f}, {y:.2f}, {z:.2f}) m: "
              f"{r['area_m2'] * 1e4:.0f} cm², peak {r['peak'] * 1e3:+.1f} mm")
        level = max(level, 2 if abs(r["peak"]) > 2 * tol else 1)
    for m in f["missing"]:
        x, y, z = m["centroid"]
        print(f"  missing material at ({x:.2f}, {y:.2f}, {z:.2f}) m: {m['area_m2'] * 1e4:.0f} cm²")
        level = 2
    print(["  within tolerance: go on printing", "  adjust and go on",
           "  stop: inspect the part before printing on"][level])
    return level


if __name__ == "__main__":
    sys.exit(main())
