"""Fit the keyscan working regions of SRF-Odometry (thesis §3.G.7), one model per 2D lidar preset.

Protocol, per preset: a robot whose scanner sits at the base origin (0.3 m high) is teleported to random scan
pairs in the training worlds. The first pose is uniform over the free space (clearance >= 0.5 m, random heading);
the second is displaced by a translation uniform in [0, 1] m in a random direction and a rotation uniform in
[0, 1] rad of random sign, and must be free too and reachable along a straight segment with 0.2 m clearance.
Both scans are cast noise-free by the simulator and get Gaussian range noise with sigma uniform in 5-25 mm
(drawn per pair). A fresh ``SRFOdometry(mode="CA")`` aligns them; the pair is *good* when the error of the
estimated motion is below 10 mm and 0.1 deg (the thresholds of §3.G.7). A logistic model of P(good | t, |r|)
whose logit is a polynomial of degree 4 (as the boundary polynomial of §3.G.7), constrained to be non-increasing
in t and |r| over the sampled domain, is fitted to the labels and saved, with the protocol and a summary, to
``simnav/odometry/keyscan_models/<preset>.json``; the working region is P(good | t, r) >= 0.9 P(good | 0, 0)
(see :mod:`simnav.odometry.keyscan`).

The training worlds are not the benchmark worlds of ``scripts/bench_laser_odometry.py`` (curved, office seed 0,
polygonal), as in the thesis, which learned the model in other maps than those it tested on.

    python scripts/fit_keyscan_models.py [--presets hokuyo_utm30lx ...] [--pairs 12000] [--seed 0]
                                         [--worlds flat desks office:generator.seed=1 ...] [--plot DIR]
                                         [--workers 2] [--out DIR] [--samples DIR]

Pairs are simulated in chunks by ``--workers`` processes; every chunk has its own seed, so the same arguments
give the same files whatever the number of workers.
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import os
import re
import time
import zlib
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.table import Table

import simnav  # first: it chooses MUJOCO_GL before mujoco loads
from simnav.geometry import se2
from simnav.odometry.keyscan import (
    DEFAULT_EXPONENTS,
    MODEL_DIR,
    MONOTONE_GRID,
    LearnedKeyscanPolicy,
    fit_working_region,
)
from simnav.odometry.srf import SRFOdometry
from simnav.robot import load_robot
from simnav.sensors.noise import lidar_noise
from simnav.sensors.presets import LIDAR2D_PRESETS
from simnav.sim import SimConfig, Simulator
from simnav.world import load_world
from simnav.world.footprint import bounds, distance_to, obstacle_union, segment_is_free

WORLDS = ("office:generator.seed=1:generator.door_leaves=false", "office:generator.seed=2:generator.door_leaves=false",
          "flat", "desks")
"""Training worlds, ``NAME[:OVERRIDE]...`` (held-out from the benchmark worlds)."""
MAX_TRANSLATION_M = 1.0
MAX_ROTATION_RAD = 1.0
NOISE_STD_M = (0.005, 0.025)
MIN_CLEARANCE_M = 0.5
PATH_CLEARANCE_M = 0.2
MAX_TRANSLATION_ERROR_M = 0.01
MAX_ROTATION_ERROR_RAD = math.radians(0.1)
P_RATIO = 0.9
MARGIN = 0.1
CHUNK_PAIRS = 250
ROBOT = "giraff"
MOUNT = "{xyz_m: [0.0, 0.0, 0.3]}"


@dataclass(frozen=True)
class Job:
    """One chunk of pairs: ``pairs`` scan pairs of ``preset`` in ``world``, seeded by ``(seed, preset, world,
    chunk)``."""

    preset: str
    world: str
    chunk: int
    pairs: int
    seed: int

    def rng(self) -> np.random.Generator:
        key = [self.seed, zlib.crc32(self.preset.encode()), zlib.crc32(self.world.encode()), self.chunk]
        return np.random.default_rng(np.random.SeedSequence(key))


# ---------------------------------------------------------------------------------------------- simulation
@functools.cache
def _scene(preset: str, world: str) -> tuple[Simulator, object, tuple[float, float, float, float]]:
    """Simulator (noise-free scanner ``preset`` at the base origin), obstacle footprint and bounds of a world."""
    name, *overrides = world.split(":")
    spec = load_world(name, overrides)
    sensor = f"[{{name: laser, type: lidar2d, preset: {preset}, noise_std_m: 0.0, mount: {MOUNT}}}]"
    robot = load_robot(ROBOT, [f"sensors={sensor}"])
    sim = Simulator(spec, robot, SimConfig(pedestrians=0, wanderers=0), seed=0)
    return sim, obstacle_union(spec, include_doors=True), bounds(spec)


def _free(geom, xy: np.ndarray) -> bool:
    return bool(distance_to(geom, xy)[0] >= MIN_CLEARANCE_M)


def sample_pair(geom, box: tuple[float, float, float, float],
                rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A free first pose and the motion to a free, reachable second one (rejection sampling).

    Returns:
        ``T_world_a`` (3, 3) and ``T_a_b`` (3, 3).
    """
    lo, hi = np.array(box[:2]), np.array(box[2:])
    while True:
        a = rng.uniform(lo, hi)
        yaw = rng.uniform(-math.pi, math.pi)
        t = rng.uniform(0.0, MAX_TRANSLATION_M)
        r = rng.uniform(0.0, MAX_ROTATION_RAD) * rng.choice([-1.0, 1.0])
        heading = rng.uniform(-math.pi, math.pi)
        if not _free(geom, a):
            continue
        T_wa = se2.from_xy_yaw(a[0], a[1], yaw)
        T_ab = se2.from_xy_yaw(t * math.cos(heading), t * math.sin(heading), r)
        b = (T_wa @ T_ab)[:2, 2]
        if _free(geom, b) and segment_is_free(geom, (a[0], a[1]), (b[0], b[1]), PATH_CLEARANCE_M):
            return T_wa, T_ab


def _scan(sim: Simulator, T_world: np.ndarray, sigma_m: float, rng: np.random.Generator):
    """A scan from pose ``T_world`` with Gaussian range noise ``sigma_m``."""
    sim.teleport(T_world[0, 2], T_world[1, 2], math.atan2(T_world[1, 0], T_world[0, 0]))
    scan = sim.capture_now("laser")
    noisy = lidar_noise(scan.ranges_m.astype(np.float64), rng, sigma_m, 0.0, scan.min_range_m, scan.max_range_m)
    return replace(scan, ranges_m=noisy)


def alignment_error(T_true: np.ndarray, T_est: np.ndarray) -> tuple[float, float]:
    """Translation (m) and |rotation| (rad) of ``inv(T_true) @ T_est``."""
    E = se2.inverse(T_true) @ T_est
    return math.hypot(E[0, 2], E[1, 2]), abs(math.atan2(E[1, 0], E[0, 0]))


def run_job(job: Job) -> np.ndarray:
    """Simulate and align the pairs of a chunk.

    Returns:
        (pairs, 5): translation m, |rotation| rad, noise sigma m, translation error m, rotation error rad.
    """
    sim, geom, box = _scene(job.preset, job.world)
    rng = job.rng()
    rows = np.empty((job.pairs, 5))
    for k in range(job.pairs):
        T_wa, T_ab = sample_pair(geom, box, rng)
        sigma = rng.uniform(*NOISE_STD_M)
        scan_a, scan_b = _scan(sim, T_wa, sigma, rng), _scan(sim, T_wa @ T_ab, sigma, rng)
        odometry = SRFOdometry(mode="CA")
        odometry.process(scan_a)
        estimate = odometry.process(scan_b)
        err_t, err_r = alignment_error(T_ab, estimate.T_odom_base)
        rows[k] = (math.hypot(T_ab[0, 2], T_ab[1, 2]), abs(math.atan2(T_ab[1, 0], T_ab[0, 0])), sigma, err_t, err_r)
    return rows


def make_jobs(presets: list[str], worlds: list[str], pairs: int, seed: int) -> list[Job]:
    """Chunks of at most ``CHUNK_PAIRS``; each preset gets ``pairs`` pairs split evenly over the worlds."""
    jobs = []
    for preset in presets:
        for w, world in enumerate(worlds):
            n = pairs // len(worlds) + (w < pairs % len(worlds))
            for chunk, start in enumerate(range(0, n, CHUNK_PAIRS)):
                jobs.append(Job(preset, world, chunk, min(CHUNK_PAIRS, n - start), seed))
    return jobs


def simulate(jobs: list[Job], workers: int, console: Console) -> dict[Job, np.ndarray]:
    """Run every job (in ``workers`` processes when > 1) with a progress bar."""
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TextColumn("pairs"),
               TimeElapsedColumn(), TimeRemainingColumn())
    results: dict[Job, np.ndarray] = {}
    with Progress(*columns, console=console) as bar:
        task = bar.add_task("simulating scan pairs", total=sum(j.pairs for j in jobs))
        if workers <= 1:
            for job in jobs:
                bar.update(task, description=f"{job.preset} in {job.world.split(':')[0]}")
                results[job] = run_job(job)
                bar.advance(task, job.pairs)
            return results
        with ProcessPoolExecutor(max_workers=workers) as pool:
            futures = {pool.submit(run_job, job): job for job in jobs}
            for future in as_completed(futures):
                job = futures[future]
                results[job] = future.result()
                bar.update(task, description=f"{job.preset} in {job.world.split(':')[0]}")
                bar.advance(task, job.pairs)
    return results


# --------------------------------------------------------------------------------------------------- fitting
def is_good(samples: np.ndarray) -> np.ndarray:
    """(N,) labels of (N, 5) samples: both errors below the §3.G.7 thresholds."""
    return (samples[:, 3] <= MAX_TRANSLATION_ERROR_M) & (samples[:, 4] <= MAX_ROTATION_ERROR_RAD)


def _round(x: float, digits: int = 6) -> float:
    return float(f"{x:.{digits}g}")


def fit_preset(preset: str, per_world: dict[str, np.ndarray], seed: int) -> tuple[LearnedKeyscanPolicy, dict]:
    """The policy fitted to a preset's samples, and its JSON document."""
    samples = np.vstack(list(per_world.values()))
    good = is_good(samples)
    coefficients = fit_working_region(samples[:, 0], samples[:, 1], good, DEFAULT_EXPONENTS, MAX_TRANSLATION_M,
                                      MAX_ROTATION_RAD)
    policy = LearnedKeyscanPolicy(DEFAULT_EXPONENTS, tuple(_round(c, 10) for c in coefficients), P_RATIO, MARGIN,
                                  MAX_TRANSLATION_M, MAX_ROTATION_RAD, preset)
    p = LIDAR2D_PRESETS[preset]
    doc = policy.to_dict()
    doc["model"]["features"] = "P(good) = sigmoid(sum_k c_k t^i_k |r|^j_k), t: translation m, r: rotation rad"
    grid = f"{MONOTONE_GRID} x {MONOTONE_GRID}"
    doc["model"]["fit"] = f"maximum likelihood, logit non-increasing in t and |r| on a {grid} grid over the domain"
    doc["scanner"] = {"beams": p.beams, "fov_deg": p.fov_deg, "max_range_m": p.max_range_m}
    doc["labels"] = {"good": "translation error <= max_translation_error_m and rotation error <= "
                             "max_rotation_error_rad (thesis 3.G.7: 10 mm, 0.1 deg)",
                     "max_translation_error_m": MAX_TRANSLATION_ERROR_M,
                     "max_rotation_error_rad": _round(MAX_ROTATION_ERROR_RAD)}
    doc["summary"] = {
        "p_good_at_rest": _round(policy.probability_good(0.0, 0.0)), "level": _round(policy.level),
        "max_translation_m_at_zero_rotation": _round(policy.max_translation(0.0)),
        "max_rotation_rad_at_zero_translation": _round(policy.max_rotation(0.0)),
        "good_fraction": _round(float(good.mean())),
        "good_fraction_per_world": {w: _round(float(is_good(s).mean())) for w, s in per_world.items()},
    }
    doc["protocol"] = {
        "script": "scripts/fit_keyscan_models.py", "seed": seed, "odometry": "SRFOdometry(mode='CA'), defaults",
        "robot": ROBOT, "mount": "scanner at the base origin, 0.3 m above the floor",
        "worlds": list(per_world), "pairs": int(len(samples)),
        "pairs_per_world": {w: int(len(s)) for w, s in per_world.items()}, "good_pairs": int(good.sum()),
        "translation_m": [0.0, MAX_TRANSLATION_M], "rotation_rad": [0.0, MAX_ROTATION_RAD],
        "noise_std_m": list(NOISE_STD_M), "min_clearance_m": MIN_CLEARANCE_M,
        "path_clearance_m": PATH_CLEARANCE_M,
    }
    return policy, doc


def plot(policy: LearnedKeyscanPolicy, samples: np.ndarray, path: Path) -> None:
    """Scatter of good / bad pairs with the working-region boundary (and the margin-shrunk one)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    good = is_good(samples)
    fig, ax = plt.subplots(figsize=(6.4, 5.2))
    ax.scatter(samples[good, 0], samples[good, 1], s=3, c="tab:green", alpha=0.35, lw=0, label="good")
    ax.scatter(samples[~good, 0], samples[~good, 1], s=3, c="tab:red", alpha=0.35, lw=0, label="bad")
    t, r = np.meshgrid(np.linspace(0, MAX_TRANSLATION_M, 201), np.linspace(0, MAX_ROTATION_RAD, 201))
    prob = policy.probabilities(t.ravel(), r.ravel()).reshape(t.shape)
    ax.contour(t, r, prob, levels=[policy.level], colors="k", linewidths=2)
    s = 1.0 + policy.margin
    scaled = policy.probabilities(s * t.ravel(), s * r.ravel()).reshape(t.shape)
    scaled[(s * t > policy.max_translation_m) | (s * r > policy.max_rotation_rad)] = 0.0
    ax.contour(t, r, scaled, levels=[policy.level], colors="k", linewidths=1, linestyles="--")
    cs = ax.contour(t, r, prob, levels=[0.3, 0.5, 0.7], colors="0.5", linewidths=0.8)
    ax.clabel(cs, fontsize=7)
    ax.plot([], [], "k-", lw=2, label=f"P(good) = {policy.p_ratio:g} P(good | 0, 0) = {policy.level:.2f}")
    ax.plot([], [], "k--", lw=1, label=f"keyscan trigger (margin {policy.margin:g})")
    ax.set(xlabel="translation between scans (m)", ylabel="|rotation| between scans (rad)",
           xlim=(0, MAX_TRANSLATION_M), ylim=(0, MAX_ROTATION_RAD),
           title=f"{policy.name}: {good.sum()} good / {len(good)} pairs (10 mm, 0.1 deg)")
    ax.legend(loc="upper right", fontsize=7, markerscale=3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def save_samples(per_world: dict[str, np.ndarray], path: Path) -> None:
    """Raw samples: (N, 5) ``samples`` (see :func:`run_job`), (N,) ``world`` index, and the ``worlds``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    index = np.concatenate([np.full(len(s), k) for k, s in enumerate(per_world.values())])
    samples = np.vstack(list(per_world.values()))
    np.savez_compressed(path, samples=samples, world=index, worlds=np.array(list(per_world)))


def write_json(doc: dict, path: Path) -> None:
    """``doc`` as indented JSON with every list of numbers on one line."""
    flat = lambda m: "[" + ", ".join(x.strip() for x in m.group(1).split(",")) + "]"
    text = re.sub(r"\[\s*([-+.0-9e,\s]+?)\s*\]", flat, json.dumps(doc, indent=2))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text + "\n", encoding="utf-8")


# ------------------------------------------------------------------------------------------------------ main
def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--presets", nargs="+", default=sorted(LIDAR2D_PRESETS), choices=sorted(LIDAR2D_PRESETS))
    parser.add_argument("--pairs", type=int, default=12000, help="scan pairs per preset (split over the worlds)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--worlds", nargs="+", default=list(WORLDS), help="NAME[:OVERRIDE]... (default: %(default)s)")
    parser.add_argument("--plot", type=Path, default=None, help="folder for one PNG per preset")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--out", type=Path, default=MODEL_DIR, help="folder of the JSON models (default: shipped)")
    parser.add_argument("--samples", type=Path, default=None, help="folder for one .npz of raw samples per preset")
    args = parser.parse_args()
    if args.pairs < 10 * len(DEFAULT_EXPONENTS):
        parser.error(f"--pairs must be at least {10 * len(DEFAULT_EXPONENTS)}")
    console = Console()
    t0 = time.perf_counter()
    jobs = make_jobs(args.presets, args.worlds, args.pairs, args.seed)
    results = simulate(jobs, args.workers, console)
    table = Table("preset", "pairs", "good", "P(good|0,0)", "t_max (m) at r=0", "r_max (rad) at t=0", "file",
                  title=f"keyscan working regions (simnav {simnav.__version__}, {time.perf_counter() - t0:.0f} s)")
    for preset in args.presets:
        per_world = {w: np.vstack([results[j] for j in jobs if j.preset == preset and j.world == w])
                     for w in args.worlds}
        policy, doc = fit_preset(preset, per_world, args.seed)
        path = args.out / f"{preset}.json"
        write_json(doc, path)
        if args.samples is not None:
            save_samples(per_world, args.samples / f"{preset}.npz")
        if args.plot is not None:
            args.plot.mkdir(parents=True, exist_ok=True)
            plot(policy, np.vstack(list(per_world.values())), args.plot / f"{preset}.png")
        s = doc["summary"]
        extents = (s["max_translation_m_at_zero_rotation"], s["max_rotation_rad_at_zero_translation"])
        table.add_row(preset, str(doc["protocol"]["pairs"]), f"{s['good_fraction']:.1%}",
                      f"{s['p_good_at_rest']:.3f}", f"{extents[0]:.3f}", f"{extents[1]:.3f}", str(path))
    console.print(table)


if __name__ == "__main__":
    main()
