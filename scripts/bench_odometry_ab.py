"""Paired A/B runtime of DIFODO or Joint-VO-SF between two versions of simnav, on the same frames and cores.

The machine's speed can swing by 2x within minutes, so two separate runs of ``bench_difodo_runtime.py`` or
``bench_vosf_runtime.py`` do not compare two versions. This script renders the synthetic frames of those scripts
once (QVGA by default), exports each git revision (``git archive``) into a temporary folder, starts one persistent
worker per version pinned to the same cores (``--threads``: 1 for DIFODO as its bench, 2 for Joint-VO-SF's target),
and alternates passes over the frames between them (a fresh odometry per pass, after a warm-up pass that compiles or
loads the Numba kernels). It prints each version's median time per frame (first frame of a pass left out), the
median of the paired ratios B/A, which the swings cancel out of, and the largest difference between the two
versions' final poses.

    python scripts/bench_odometry_ab.py BASE_REV [NEW_REV] [--method difodo|vosf] [--rounds 20] [--frames 40]
                                        [--resolution qvga|qqvga] [--threads 1] [--sequence NAME]

``--sequence NAME`` takes the first ``--frames`` frames of a simulated office sequence of
``scripts/bench_rgbd_odometry.py`` (e.g. ``handheld-people4``; read from its cache, simulated there first if needed)
instead of the synthetic frames: the office's frames need more work per frame than the synthetic room's.

``NEW_REV`` defaults to the working tree (not an export: uncommitted changes count).
"""

from __future__ import annotations

import argparse
import os
import pickle
import statistics
import tempfile
from pathlib import Path

import numpy as np

from bench_env_ab import ROOT, alternate, export, start_worker

WORKER = """
import pickle, sys, time
import numpy as np
import simnav
method, frames_file = sys.argv[1], sys.argv[2]
with open(frames_file, "rb") as f:
    frames = pickle.load(f)
if method == "difodo":
    from simnav.odometry.difodo import DIFODO as Odometry
    kwargs = {"max_rows": frames[0].depth_m.shape[0]}
else:
    from simnav.odometry.vosf import JointVOSF as Odometry
    kwargs = {}
def run():
    odo, times, est = Odometry(**kwargs), [], None
    for frame in frames:
        t0 = time.perf_counter()
        est = odo.process(frame)
        times.append(time.perf_counter() - t0)
    return float(np.median(times[1:])), est.T_odom_camera
run()
print("ready", simnav.__file__, flush=True)
for line in sys.stdin:
    median_s, T = run()
    print(median_s, " ".join(repr(float(x)) for x in T.ravel()), flush=True)
"""


def make_frames(method: str, resolution: str, n: int) -> list:
    """The frames of the method's runtime bench: DIFODO's box room or Joint-VO-SF's textured room with a walker."""
    if method == "difodo":
        import bench_difodo_runtime as bench

        shape = bench.RESOLUTIONS[resolution.upper()]
        return bench.make_frames(shape, bench.base_poses(n), 1.5e-3)
    import bench_vosf_runtime as bench

    return bench.make_frames(n, *bench.RESOLUTIONS[resolution])[0]


def office_frames(name: str, n: int) -> list:
    """The first n frames of the bench sequence ``name`` of ``bench_rgbd_odometry.py`` (seed 0, 10 s, as its
    defaults), from its cache under ``runs/bench_rgbd_cache`` (simulated first if missing)."""
    import bench_rgbd_odometry as rgbd

    if name not in rgbd.ALL_SEQUENCES:
        raise SystemExit(f"--sequence must be one of {', '.join(rgbd.ALL_SEQUENCES)}, got {name!r}")
    folder = rgbd.simulate(name, 10.0, 0, 4, print)
    return rgbd.load(folder).frames[:n]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("base", help="git revision A")
    parser.add_argument("new", nargs="?", help="git revision B (default: the working tree)")
    parser.add_argument("--method", choices=["difodo", "vosf"], default="difodo")
    parser.add_argument("--rounds", type=int, default=20, help="passes over the frames per version")
    parser.add_argument("--frames", type=int, default=40, help="frames per pass")
    parser.add_argument("--resolution", choices=["qvga", "qqvga"], default="qvga")
    parser.add_argument("--threads", type=int, default=1, help="cores pinned and threads per library")
    parser.add_argument("--sequence", help="frames of this office sequence of bench_rgbd_odometry.py (QVGA)")
    args = parser.parse_args()
    cores = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else list(range(os.cpu_count() or 1))
    if args.threads < 1 or args.threads > len(cores):
        raise SystemExit(f"--threads must be between 1 and {len(cores)}, got {args.threads}")
    pinned = ",".join(str(c) for c in cores[-args.threads:])
    frames = (office_frames(args.sequence, args.frames) if args.sequence
              else make_frames(args.method, args.resolution, args.frames))
    with tempfile.TemporaryDirectory() as tmp:
        frames_file = Path(tmp) / "frames.pkl"
        frames_file.write_bytes(pickle.dumps(frames))
        trees = [export(args.base, Path(tmp) / "a"), export(args.new, Path(tmp) / "b") if args.new else ROOT]
        print(f"starting the workers (the first start in a fresh export compiles the kernels) on cores {pinned}")
        limits = {var: str(args.threads) for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                                                     "NUMBA_NUM_THREADS")}
        workers = [start_worker(tree, WORKER, [args.method, str(frames_file)], pinned, limits) for tree in trees]
        replies = [[line.split() for line in lines] for lines in alternate(workers, args.rounds, "pass")]
        times = [[float(fields[0]) for fields in rows] for rows in replies]
        poses = [np.array([float(x) for x in rows[-1][1:]]).reshape(4, 4) for rows in replies]
    names = [args.base, args.new or "working tree"]
    print(f"{args.method} {args.sequence or args.resolution}, {len(frames)} frames per pass, {args.rounds} passes "
          f"each, {args.threads} thread(s)")
    for name, ts in zip(names, times, strict=True):
        print(f"{name}: median {1e3 * statistics.median(ts):.2f} ms per frame (best pass {1e3 * min(ts):.2f})")
    paired = statistics.median(b / a for a, b in zip(times[0], times[1], strict=True))
    print(f"B/A time per frame: median of the paired ratios {paired:.3f}")
    print(f"largest difference of the final poses: {np.abs(poses[0] - poses[1]).max():.2e}")


if __name__ == "__main__":
    main()
