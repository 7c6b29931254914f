"""Runtime per frame of Joint-VO-SF (:mod:`simnav.odometry.vosf`) at QQVGA and QVGA on synthetic RGB-D frames.

A pure-numpy ray caster renders a 6 x 5 x 3 m room with value-noise textures, four static boxes (furniture) and a
0.4 x 0.7 x 1.7 m box walking at 1.5 m/s across the view (about 30 % of the image) — the scene of
``tests/odometry/test_vosf.py``. The camera (60 degree horizontal field of view, 30 Hz) rests for one frame, then
moves 1.6 cm and 0.73 degrees per frame. Every resolution runs the same trajectory, pinned to ``--threads`` CPU
cores (default 1) with that many threads per library: Numba's per-pixel kernels split their loops over the finest
QVGA level between them, with the same numbers for any thread count (idle threads sleep: OMP_WAIT_POLICY=passive).
Per resolution the script prints the median and p95 wall time per frame (the first frame only builds its pyramid and
clusters and is left out), the median CPU time of the calling thread ("cpu", less sensitive to other load on the
machine; with several threads, its share of the work: it sleeps while waiting for the others) and of all threads
("all cpu": the total work), the mean error of the frame-to-frame motion against ground truth and the share of the
walking box's pixels flagged moving; each resolution runs ``--repeats`` times and the pass with the lowest median is
kept. With ``--cold`` a fresh process with an empty Numba cache also times the first two frames (compiling the
kernels).

    python scripts/bench_vosf_runtime.py [--threads 1] [--frames 40] [--resolutions qqvga qvga] [--repeats 3] [--cold]
"""

from __future__ import annotations

import os
import sys


def _threads_argument(argv: list[str]) -> int:
    """The value of ``--threads`` (1 without it), read before Numba is imported: its thread pool size is fixed then."""
    for i, arg in enumerate(argv):
        if arg.startswith("--threads="):
            value = arg.partition("=")[2]
        elif arg == "--threads" and i + 1 < len(argv):
            value = argv[i + 1]
        else:
            continue
        return int(value) if value.isdigit() and int(value) >= 1 else 1  # argparse reports a bad value
    return 1


THREADS = _threads_argument(sys.argv)
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = str(THREADS)  # no library may spread a frame over more threads than pinned cores
os.environ.setdefault("OMP_WAIT_POLICY", "passive")  # as simnav.odometry.vosf_kernels sets it: idle threads sleep

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import subprocess  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
from rich.console import Console  # noqa: E402
from rich.table import Table  # noqa: E402

from simnav.geometry import se3  # noqa: E402
from simnav.geometry.camera import R_BODY_OPTICAL  # noqa: E402
from simnav.sensors.readings import RGBDFrame  # noqa: E402

RESOLUTIONS = {"qqvga": (120, 160), "qvga": (240, 320), "vga": (480, 640)}
HFOV_DEG, DT_S = 60.0, 1.0 / 30.0
ROOM_HI = np.array([6.0, 5.0, 3.0])
XI_CAM = np.array([0.006, -0.003, 0.015, 0.003, -0.012, 0.002])  # camera motion per frame (optical frame)
WALK_M = 0.05  # walking box per frame, along world +y
NOISE = [np.random.default_rng(s).random((64, 64)) for s in range(8)]


# ---------------------------------------------------------------------------------------------- frames
def _texture(a: np.ndarray, b: np.ndarray, seed: int) -> np.ndarray:
    """Contrast-stretched multi-scale value noise in [0, 1] at surface coordinates (a, b), m."""
    table, out, total = NOISE[seed % len(NOISE)], np.zeros_like(a), 0.0
    for octave, cell in enumerate((0.8, 0.4, 0.2, 0.1, 0.05)):
        s, t = a / cell + 17.3 * octave, b / cell + 5.1 * octave
        i, j = np.floor(s).astype(int), np.floor(t).astype(int)
        fs, ft = s - i, t - j
        fs, ft = fs * fs * (3 - 2 * fs), ft * ft * (3 - 2 * ft)
        v = ((1 - fs) * (1 - ft) * table[i % 64, j % 64] + fs * (1 - ft) * table[(i + 1) % 64, j % 64]
             + (1 - fs) * ft * table[i % 64, (j + 1) % 64] + fs * ft * table[(i + 1) % 64, (j + 1) % 64])
        out += 0.75**octave * v
        total += 0.75**octave
    return np.clip(0.5 + 2.5 * (out / total - 0.5), 0.0, 1.0)


def _box(x: float, y: float, z: float, half: tuple[float, float, float], yaw_deg: float, seed: int) -> tuple:
    return se3.from_rpy(0.0, 0.0, math.radians(yaw_deg), [x, y, z]), np.array(half), seed


FURNITURE = [_box(4.6, 3.9, 0.6, (0.4, 0.5, 0.6), 0.0, 5), _box(5.7, 1.0, 1.0, (0.3, 0.6, 1.0), 20.0, 4),
             _box(4.2, 2.0, 0.4, (0.3, 0.3, 0.4), -30.0, 3), _box(5.5, 2.8, 1.5, (0.15, 0.15, 1.5), 45.0, 2)]


def render(T_world_optical: np.ndarray, boxes: list[tuple], K: np.ndarray, h: int, w: int
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(depth (h, w) float32 m, rgb (h, w, 3) uint8, id (h, w))`` of the room and boxes; id = box index or -1."""
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    d = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1) @ T_world_optical[
        :3, :3].T
    o = T_world_optical[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        t_axes = np.where(d > 0, (ROOM_HI - o) / d, np.where(d < 0, -o / d, np.inf))
    t, axis = t_axes.min(axis=-1), t_axes.argmin(axis=-1)
    hit = o + t[..., None] * d
    a, b = np.where(axis == 0, hit[..., 1], hit[..., 0]), np.where(axis == 2, hit[..., 1], hit[..., 2])
    face = axis * 2 + (np.take_along_axis(d, axis[..., None], -1)[..., 0] > 0)
    shade, ids = np.zeros_like(t), np.full(t.shape, -1)
    for s in range(6):
        shade[face == s] = _texture(a[face == s] + 0.37 * s, b[face == s], s)
    for n, (T_box, half, seed) in enumerate(boxes):
        ob, db = (o - T_box[:3, 3]) @ T_box[:3, :3], d @ T_box[:3, :3]
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (-half - ob) / db, (half - ob) / db
        tmin, tmax = np.nanmax(np.minimum(t1, t2), axis=-1), np.nanmin(np.maximum(t1, t2), axis=-1)
        m = (tmax >= tmin) & (tmin > 0) & (tmin < t)
        if np.any(m):
            t = np.where(m, tmin, t)
            local = ob + tmin[m, None] * db[m]
            f = np.argmax(np.abs(local) / half, axis=-1)
            shade[m] = _texture(np.where(f == 0, local[:, 1], local[:, 0]) + 1.1 * f,
                                np.where(f == 2, local[:, 1], local[:, 2]), seed)
            ids[m] = n
    gray = np.clip(0.15 + 0.75 * shade, 0, 1)
    rgb = np.clip(np.stack([gray * 1.02, gray, gray * 0.97], axis=-1) * 255 + 0.5, 0, 255).astype(np.uint8)
    return t.astype(np.float32), rgb, ids


def make_frames(n: int, h: int, w: int) -> tuple[list[RGBDFrame], list[np.ndarray]]:
    """n frames at h x w and the true camera poses ``T_world_optical``."""
    f = (w / 2) / math.tan(math.radians(HFOV_DEG / 2))
    K = np.array([[f, 0.0, (w - 1) / 2], [0.0, f, (h - 1) / 2], [0.0, 0.0, 1.0]])
    T = se3.from_rpy(0.0, math.radians(5.0), math.radians(5.0), [1.2, 2.5, 1.3]) @ se3.from_rotation_translation(
        R_BODY_OPTICAL)
    frames, poses = [], []
    for i in range(n):
        walker = _box(3.2, 2.35 - 0.5 * WALK_M * n + WALK_M * i, 0.85, (0.2, 0.35, 0.85), 35.0, 6)
        depth, rgb, ids = render(T, [walker, *FURNITURE], K, h, w)
        frames.append(RGBDFrame("cam", i * DT_S, depth, rgb, K, np.eye(4), body_id=ids))
        poses.append(T)
        if i >= 1:
            T = T @ se3.exp(XI_CAM * (1.0 + 0.2 * math.sin(0.3 * i)))
    return frames, poses


# ---------------------------------------------------------------------------------------------- timing
def _positive(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError("must be >= 1")
    return value


def pin_cores(n: int) -> set[int]:
    """Pins the process (and the threads it starts later) to the first n cores it may run on; returns them."""
    if not hasattr(os, "sched_setaffinity"):
        return set(range(n))
    allowed = sorted(os.sched_getaffinity(0))
    if len(allowed) < n:
        raise SystemExit(f"--threads {n}: only {len(allowed)} core(s) available")
    os.sched_setaffinity(0, set(allowed[:n]))
    return set(allowed[:n])


def run(frames: list[RGBDFrame], poses: list[np.ndarray], repeats: int, config: dict) -> dict:
    """Runs Joint-VO-SF ``repeats`` times over the frames (fresh instances after a warm-up pass on 3 frames).

    Returns:
        ``median_ms``, ``p95_ms`` (wall), ``cpu_median_ms`` (calling thread) and ``all_cpu_median_ms`` (all
        threads) per aligned frame of the pass with the lowest wall median; ``err_mm`` / ``err_deg``: mean error of
        the frame-to-frame motions; ``moving``: share of the walking box's pixels flagged moving;
        ``static_moving``: share of the other pixels flagged moving.
    """
    from simnav.odometry.vosf import JointVOSF

    warm = JointVOSF(**config)
    for f in frames[:3]:
        warm.process(f)
    best = None
    for _ in range(repeats):
        odo, wall, cpu, all_cpu, est = JointVOSF(**config), [], [], [], []
        for f in frames:
            t0, c0, a0 = time.perf_counter(), time.thread_time(), time.process_time()
            est.append(odo.process(f))
            wall.append(time.perf_counter() - t0)
            cpu.append(time.thread_time() - c0)
            all_cpu.append(time.process_time() - a0)
        r = (1e3 * np.array(wall[1:]), 1e3 * np.array(cpu[1:]), 1e3 * np.array(all_cpu[1:]), est)
        best = r if best is None or np.median(r[0]) < np.median(best[0]) else best
    wall_ms, cpu_ms, all_cpu_ms, est = best
    errs, moving, static_moving = [], [], []
    for i in range(1, len(frames)):
        E = se3.inverse(se3.inverse(poses[i - 1]) @ poses[i]) @ se3.inverse(est[i - 1].T_odom_camera) @ est[
            i].T_odom_camera
        errs.append((1e3 * np.linalg.norm(E[:3, 3]), math.degrees(np.linalg.norm(se3.so3_log(E[:3, :3])))))
        walker, mask = frames[i].body_id == 0, est[i].extra["moving_mask"]
        if walker.any():
            moving.append(mask[walker].mean())
        static_moving.append(mask[~walker].mean())
    errs = np.array(errs)
    return {"median_ms": float(np.median(wall_ms)), "p95_ms": float(np.percentile(wall_ms, 95)),
            "cpu_median_ms": float(np.median(cpu_ms)), "all_cpu_median_ms": float(np.median(all_cpu_ms)),
            "err_mm": float(errs[:, 0].mean()), "err_deg": float(errs[:, 1].mean()),
            "moving": float(np.mean(moving)), "static_moving": float(np.mean(static_moving))}


def cold_child(resolution: str) -> None:
    """In a fresh process: prints JSON with the import time and the wall time of the first two frames, ms."""
    frames, _ = make_frames(2, *RESOLUTIONS[resolution])
    t0 = time.perf_counter()
    from simnav.odometry.vosf import JointVOSF

    out, odo = {"import_ms": 1e3 * (time.perf_counter() - t0)}, JointVOSF()
    for i, f in enumerate(frames):
        t0 = time.perf_counter()
        odo.process(f)
        out[f"frame{i}_ms"] = 1e3 * (time.perf_counter() - t0)
    print(json.dumps(out))


def cold(resolution: str) -> dict:
    """:func:`cold_child` in a fresh interpreter with an empty Numba cache."""
    with tempfile.TemporaryDirectory() as cache:
        proc = subprocess.run([sys.executable, __file__, "--threads", str(THREADS), "--cold-child", resolution],
                              capture_output=True, text=True, check=True, env=dict(os.environ, NUMBA_CACHE_DIR=cache))
    return json.loads(proc.stdout.strip().splitlines()[-1])


# ---------------------------------------------------------------------------------------------- report
def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=_positive, default=1, help="CPU cores pinned and threads per library")
    parser.add_argument("--frames", type=int, default=40, help="frames per sequence")
    parser.add_argument("--resolutions", nargs="+", default=["qqvga", "qvga"], choices=list(RESOLUTIONS))
    parser.add_argument("--repeats", type=int, default=3, help="passes per resolution; the lowest median is kept")
    parser.add_argument("--no-segmentation", action="store_true", help="also time the plain robust odometry")
    parser.add_argument("--cold", action="store_true", help="time the first frames with an empty Numba cache")
    parser.add_argument("--cold-child", help=argparse.SUPPRESS)
    args = parser.parse_args()
    cores = pin_cores(args.threads)
    if args.cold_child:
        cold_child(args.cold_child)
        return
    import numba

    print(f"mode: {args.threads} thread(s) pinned to core(s) {sorted(cores)}; Numba {numba.get_num_threads()} "
          "thread(s)")
    table = Table(title=f"Joint-VO-SF runtime per frame, {args.threads} core(s)")
    for c in ("resolution", "variant", "median ms", "p95 ms", "cpu median ms", "all cpu median ms", "err mm",
              "err deg", "walker moving", "others moving", "cold frames 1-2 s"):
        table.add_column(c, justify="left" if c in ("resolution", "variant") else "right")
    variants = [("joint", {})] + ([("robust only", {"segmentation": False})] if args.no_segmentation else [])
    for res in args.resolutions:
        frames, poses = make_frames(args.frames, *RESOLUTIONS[res])
        c = cold(res) if args.cold else None
        for name, config in variants:
            r = run(frames, poses, args.repeats, config)
            cold_s = f"{(c['frame0_ms'] + c['frame1_ms']) / 1e3:.1f}" if c and name == "joint" else "-"
            table.add_row(f"{res} {RESOLUTIONS[res][1]}x{RESOLUTIONS[res][0]}", name, f"{r['median_ms']:.1f}",
                          f"{r['p95_ms']:.1f}", f"{r['cpu_median_ms']:.1f}", f"{r['all_cpu_median_ms']:.1f}",
                          f"{r['err_mm']:.2f}",
                          f"{r['err_deg']:.3f}", f"{100 * r['moving']:.0f} %", f"{100 * r['static_moving']:.1f} %",
                          cold_s)
    Console(width=180).print(table)
    print("cpu: CPU time of the calling thread; all cpu: of all threads; err: mean error of the frame-to-frame "
          "camera motion against ground truth; walker / others moving: share of the walking box's / the other pixels "
          "in moving clusters; cold: a new process with an empty Numba cache (compiling the kernels) runs the first "
          "two frames.")


if __name__ == "__main__":
    main()
