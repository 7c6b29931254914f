"""Runtime per scan of the range-flow odometries RF2O and SRF-Odometry (CA, KA, MA) on 1080-beam scans.

A scanner like the Hokuyo UTM-30LX (1080 beams over 270 degrees, sigma = 1 cm, 30 m) drives ~300 scans at 10 Hz
around a loop in an irregular L-shaped room; the scans are ray cast in pure numpy (the walls of the odometry
tests). Every method runs on the same scans, pinned to one CPU core. Per method the script prints the median and
p95 wall time per scan (the first scan of a sequence only builds its pyramid and is left out) and the median CPU
time of the thread (less sensitive to other load on the machine); each method runs ``--repeats`` times and the
pass with the lowest median is kept. Next to them: the numbers before the Numba kernels (``BEFORE_MS``, or a run
saved with ``--save`` and passed as ``--baseline``) and the last pose's error against ground truth, which must not
change. Each method is also started in a fresh process to time its import and first scans (loading the compiled
kernels from the cache; with ``--cold`` also from an empty cache, i.e. compiling them).

    python scripts/bench_scan_odometry_runtime.py [--scans 300] [--methods rf2o srf-ca srf-ka srf-ma]
                                                  [--repeats 3] [--cold] [--save FILE] [--baseline FILE]

The numpy implementation (commit 023d2bd) is measured the same way from an export of that commit:

    git archive 023d2bd simnav | tar -x -C /tmp/numpy-rangeflow
    (cd /tmp && PYTHONPATH=/tmp/numpy-rangeflow python $OLDPWD/scripts/bench_scan_odometry_runtime.py \\
        --save $OLDPWD/runs/scan_odometry_runtime_numpy.json)
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # one core: no library may spread a scan over threads

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from rich.console import Console  # noqa: E402
from rich.table import Table  # noqa: E402

from simnav.geometry.raycast2d import first_hits  # noqa: E402
from simnav.geometry import se2  # noqa: E402
from simnav.sensors.readings import LaserScan  # noqa: E402

METHODS = {"rf2o": ("rf2o", {}), "srf-ca": ("srf", {"mode": "CA"}), "srf-ka": ("srf", {"mode": "KA"}),
           "srf-ma": ("srf", {"mode": "MA"})}
MODULES = {"rf2o": "simnav.odometry.rf2o", "srf": "simnav.odometry.srf"}
BEAMS, FOV_DEG, NOISE_M, MAX_RANGE_M, MIN_RANGE_M = 1080, 270.0, 0.01, 30.0, 0.05
SCAN_DT_S = 0.1
BEFORE_MS = {"rf2o": (2.15, 2.26), "srf-ca": (2.78, 2.96), "srf-ka": (3.25, 3.47), "srf-ma": (3.90, 4.22)}
"""Median and p95 ms per scan of the numpy implementation (commit 023d2bd) on the development machine."""


# ------------------------------------------------------------------------------------------------- scans
def _box(cx: float, cy: float, w: float, h: float, yaw_deg: float) -> np.ndarray:
    """(4, 4) wall segments of a w x h rectangle centred at (cx, cy), m, rotated by ``yaw_deg``."""
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    local = np.array([[-w, -h], [w, -h], [w, h], [-w, h]]) / 2
    p = local @ np.array([[c, s], [-s, c]]) + (cx, cy)
    return np.hstack([p, np.roll(p, -1, axis=0)])


def l_room() -> np.ndarray:
    """(M, 4) walls ``x0, y0, x1, y1`` of an 8 x 6 m L-shaped room with a slanted wall, a pillar and boxes, m."""
    p = np.array([(0, 0), (8, 0), (8, 2.5), (6.5, 3.2), (5, 3.2), (5, 6), (0, 6)], dtype=np.float64)
    walls = np.hstack([p, np.roll(p, -1, axis=0)])
    return np.vstack([walls, _box(2.0, 1.2, 0.6, 0.4, 20), _box(6.6, 1.0, 0.5, 0.5, 0),
                      _box(1.2, 4.6, 0.8, 0.3, -35), _box(3.9, 4.8, 0.25, 0.25, 10)])


def loop_poses(n: int, speed_mps: float = 0.4, radius_m: float = 0.8) -> list[np.ndarray]:
    """n (3, 3) scanner poses ``SCAN_DT_S`` apart on a wobbling circle in the lower arm of :func:`l_room`."""
    poses, T = [], se2.from_xy_yaw(3.6, 0.8, 0.0)
    for i in range(n):
        poses.append(T)
        w = speed_mps / radius_m + 0.3 * math.cos(2 * math.pi * i * SCAN_DT_S / 4.0)
        T = T @ se2.exp(np.array([speed_mps * SCAN_DT_S, 0.0, w * SCAN_DT_S]))
    return poses


def make_scans(n: int, seed: int = 0) -> tuple[list[LaserScan], list[np.ndarray]]:
    """n noisy 1080-beam scans along :func:`loop_poses` and those poses (scanner = base)."""
    walls, rng = l_room(), np.random.default_rng(seed)
    half = math.radians(FOV_DEG) / 2
    angles = np.linspace(-half, half, BEAMS)
    poses, scans = loop_poses(n), []
    for i, T in enumerate(poses):
        a = angles + math.atan2(T[1, 0], T[0, 0])
        directions = np.column_stack([np.cos(a), np.sin(a)])
        r = first_hits(walls, T[:2, 2], directions) + rng.normal(scale=NOISE_M, size=BEAMS)
        r = np.where((r >= MIN_RANGE_M) & (r <= MAX_RANGE_M), r, 0.0)
        scans.append(LaserScan("laser", i * SCAN_DT_S, r.astype(np.float32), angles.copy(), MAX_RANGE_M,
                               MIN_RANGE_M, np.eye(4)))
    return scans, poses


# ---------------------------------------------------------------------------------------------- timing
def make_method(name: str):
    """A fresh odometry for a method name of :data:`METHODS`."""
    from simnav.odometry import make_scan_odometry

    kind, config = METHODS[name]
    return make_scan_odometry(kind, **config)


def run_method(name: str, scans: list[LaserScan], poses: list[np.ndarray], repeats: int) -> dict:
    """Runs one method over the scans ``repeats`` times (fresh instances, after a short warm-up).

    Returns:
        ``median_ms``, ``p95_ms`` (wall) and ``cpu_median_ms`` per aligned scan of the pass with the lowest wall
        median, ``final_error_cm`` / ``final_error_deg`` of its last pose against ground truth.
    """
    warm = make_method(name)
    for scan in scans[:5]:
        warm.process(scan)
    best = None
    for _ in range(repeats):
        odo, wall, cpu = make_method(name), [], []
        for scan in scans:
            t0, c0 = time.perf_counter(), time.thread_time()
            est = odo.process(scan)
            wall.append(time.perf_counter() - t0)
            cpu.append(time.thread_time() - c0)
        run = (1e3 * np.array(wall[1:]), 1e3 * np.array(cpu[1:]), est)
        best = run if best is None or np.median(run[0]) < np.median(best[0]) else best
    wall_ms, cpu_ms, est = best
    E = se2.inverse(se2.inverse(poses[0]) @ poses[-1]) @ est.T_odom_base
    return {"median_ms": float(np.median(wall_ms)), "p95_ms": float(np.percentile(wall_ms, 95)),
            "cpu_median_ms": float(np.median(cpu_ms)), "final_error_cm": 100 * math.hypot(E[0, 2], E[1, 2]),
            "final_error_deg": abs(math.degrees(math.atan2(E[1, 0], E[0, 0])))}


def first_scans_child(name: str) -> None:
    """In a fresh process: prints JSON with the import time of the method's module and of its first 3 scans, ms."""
    scans, _ = make_scans(3)
    t0 = time.perf_counter()
    __import__(MODULES[METHODS[name][0]])
    out = {"import_ms": 1e3 * (time.perf_counter() - t0)}
    odo = make_method(name)
    for i, scan in enumerate(scans):
        t0 = time.perf_counter()
        odo.process(scan)
        out[f"scan{i}_ms"] = 1e3 * (time.perf_counter() - t0)
    print(json.dumps(out))


def first_scans(name: str, cold: bool) -> dict:
    """Runs :func:`first_scans_child` for a method in a fresh interpreter; ``cold`` gives it an empty Numba cache."""
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache) if cold else None
        proc = subprocess.run([sys.executable, __file__, "--first-scans-child", name], capture_output=True,
                              text=True, check=True, env=env)
    return json.loads(proc.stdout.strip().splitlines()[-1])


# ---------------------------------------------------------------------------------------------- report
def _fmt(value: float | None, digits: int = 2) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def print_table(results: dict, before: dict) -> None:
    """One row per method: runtime now and before, speed-up, final error, first scans in fresh processes."""
    table = Table(title=f"Runtime per {BEAMS}-beam scan, one core")
    cols = ["method", "median ms", "p95 ms", "cpu median ms", "before median", "before p95", "speed-up",
            "end err cm", "end err deg", "fresh: import ms", "scan 1 ms", "scan 2 ms", "scan 3 ms", "cold scans 1-2 s"]
    for c in cols:
        table.add_column(c, justify="left" if c == "method" else "right")
    for name, r in results.items():
        b_med, b_p95 = before.get(name, (None, None))
        f, cold = r.get("first", {}), r.get("cold", {})
        cold_s = (cold["scan0_ms"] + cold["scan1_ms"]) / 1e3 if cold else None
        table.add_row(name, _fmt(r["median_ms"], 3), _fmt(r["p95_ms"], 3), _fmt(r["cpu_median_ms"], 3),
                      _fmt(b_med, 3), _fmt(b_p95, 3), _fmt(b_med and b_med / r["median_ms"], 1) + "x" * bool(b_med),
                      _fmt(r["final_error_cm"], 3), _fmt(r["final_error_deg"], 3), _fmt(f.get("import_ms"), 0),
                      _fmt(f.get("scan0_ms"), 1), _fmt(f.get("scan1_ms"), 1), _fmt(f.get("scan2_ms"), 2),
                      _fmt(cold_s, 1))
    Console(width=190).print(table)
    print("end err: last pose against ground truth. fresh: a new process imports the method and runs 3 scans "
          "(scan 2 is the first alignment); cold: the same with an empty Numba cache (compiling).")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", type=int, default=300, help="scans in the sequence")
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    parser.add_argument("--repeats", type=int, default=3, help="passes per method; the lowest median is kept")
    parser.add_argument("--cold", action="store_true", help="also time the first scans with an empty Numba cache")
    parser.add_argument("--no-first-scans", action="store_true", help="skip the fresh-process timings")
    parser.add_argument("--save", type=Path, help="write the results as JSON")
    parser.add_argument("--baseline", type=Path, help="JSON of an earlier run (--save) to show as 'before'")
    parser.add_argument("--first-scans-child", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    if args.first_scans_child:
        first_scans_child(args.first_scans_child)
        return
    scans, poses = make_scans(args.scans)
    results = {}
    for name in args.methods:
        results[name] = run_method(name, scans, poses, args.repeats)
        if not args.no_first_scans:
            results[name]["first"] = first_scans(name, cold=False)
            if args.cold:
                results[name]["cold"] = first_scans(name, cold=True)
    if args.save:
        args.save.parent.mkdir(parents=True, exist_ok=True)
        args.save.write_text(json.dumps(results, indent=2))
    before = BEFORE_MS
    if args.baseline:
        before = {k: (v["median_ms"], v["p95_ms"]) for k, v in json.loads(args.baseline.read_text()).items()}
    print_table(results, before)


if __name__ == "__main__":
    main()
