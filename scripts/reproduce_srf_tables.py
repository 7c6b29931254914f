"""The SRF-Odometry ablations of the thesis (§3.G.9), as markdown tables.

- Table 3.12: squared vs robust residuals, with and without pre-weighting (SQ, SQ+PW, RF, RF+PW; consecutive
  alignment, 5 Hz, maps A-C).
- Table 3.14: symmetric vs standard range flow (SRF, NSRF; 5 Hz and 2 Hz, maps A-C).
- Table 3.15: consecutive, keyscan and multi-scan alignment (CA, KA, MA) at 5 Hz, 2 Hz, with sigma = 0.1 m noise,
  and with 3/5/7 wandering robots.

Maps: A = curved, B = office with its doors held open (the thesis' maps A-C are static; the benchmark runs the
office with its doors swinging), C = polygonal, D = polygonal with wandering robots (simulated as in
scripts/bench_laser_odometry.py: UTM-30LX, 0.5 m/s, 45 deg/s). Each cell: translational RMSE per second (cm/s),
rotational RMSE per second (deg/s) and overall drift (final position error, m).

    python scripts/reproduce_srf_tables.py [--minutes 10] [--out tables.md]
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.progress import Progress

from bench_laser_odometry import SCAN_RATE_HZ, Sequence, simulate  # same folder
from simnav.geometry import se2
from simnav.io import Trajectory
from simnav.metrics import rpe_per_second
from simnav.odometry import make_scan_odometry

MAPS = {"A": "curved", "B": "office-static", "C": "polygonal"}
VARIANTS_3_12 = {"SQ": dict(robust=False, preweighting=False), "SQ+PW": dict(robust=False),
                 "RF": dict(preweighting=False), "RF+PW": {}}
VARIANTS_3_14 = {"SRF": {}, "NSRF": dict(symmetric=False)}
MODES = {"CA": dict(mode="CA"), "KA": dict(mode="KA"), "MA": dict(mode="MA")}


def score(seq: Sequence, **config) -> tuple[float, float, float, float]:
    """(trajectory length m, RPE cm/s, RPE deg/s, final position error m) of SRF with ``config`` on ``seq``."""
    odometry = make_scan_odometry("srf", **config)
    est = np.array([se2.to_se3(odometry.process(seq.scan(k)).T_odom_base) for k in range(len(seq.stamps_s))])
    gt = np.array([se2.to_se3(se2.from_xy_yaw(*p)) for p in seq.gt_xy_yaw])
    est = gt[0] @ est  # odom starts at the first ground-truth pose
    rpe = rpe_per_second(Trajectory(seq.stamps_s, est), Trajectory(seq.stamps_s, gt))
    length = float(np.sum(np.linalg.norm(np.diff(gt[:, :2, 3], axis=0), axis=1)))
    return length, rpe.trans_rmse_cm_s, rpe.rot_rmse_deg_s, float(np.linalg.norm(est[-1, :3, 3] - gt[-1, :3, 3]))


def noisier(seq: Sequence, sigma_m: float, seed: int = 0) -> Sequence:
    """The sequence with extra Gaussian range noise, so that the total standard deviation is ``sigma_m``."""
    rng = np.random.default_rng(seed)
    extra = np.sqrt(max(sigma_m**2 - 0.01**2, 0.0))
    ranges = seq.ranges_m + rng.normal(0.0, extra, seq.ranges_m.shape).astype(np.float32)
    return replace(seq, ranges_m=np.where(seq.ranges_m > 0, np.maximum(ranges, 1e-3), 0.0).astype(np.float32))


def table(title: str, columns: list[str], rows: list[tuple[str, float, list[tuple[float, float, float]]]]) -> str:
    """A markdown table: map, length, then translational / rotational RMSE and drift for every column."""
    head = ["Map", "Length (m)"] + [f"{c} cm/s" for c in columns] + [f"{c} deg/s" for c in columns] \
        + [f"{c} drift (m)" for c in columns]
    lines = [f"### {title}", "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for label, length, cells in rows:
        values = [f"{c[0]:.3f}" for c in cells] + [f"{c[1]:.3f}" for c in cells] + [f"{c[2]:.3f}" for c in cells]
        lines.append(f"| {label} | {length:.1f} | " + " | ".join(values) + " |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    seconds = args.minutes * 60
    jobs: list[tuple[str, str, Sequence, dict[str, dict]]] = []
    base = {key: simulate(name, seconds) for key, name in MAPS.items()}
    at = {rate: {k: s.every(round(SCAN_RATE_HZ / rate)) for k, s in base.items()} for rate in (5.0, 2.0)}
    for key, seq in at[5.0].items():
        jobs.append(("Table 3.12: pre-weighting and robust minimisation (CA, 5 Hz)", key, seq, VARIANTS_3_12))
    for rate in (5.0, 2.0):
        for key, seq in at[rate].items():
            jobs.append(("Table 3.14: symmetric vs standard range flow (CA)", f"{key} ({rate:g} Hz)", seq,
                         VARIANTS_3_14))
    for rate in (5.0, 2.0):
        for key, seq in at[rate].items():
            jobs.append((f"Table 3.15: alignment strategies, {rate:g} Hz", key, seq, MODES))
    for key, seq in at[5.0].items():
        jobs.append(("Table 3.15: alignment strategies, noise sigma = 0.1 m (5 Hz)", key, noisier(seq, 0.1), MODES))
    for robots in (3, 5, 7):
        seq = simulate(f"dynamic{robots}", seconds).every(round(SCAN_RATE_HZ / 5.0))
        jobs.append(("Table 3.15: alignment strategies, moving objects (5 Hz)", f"D ({robots} robots)", seq, MODES))
    sections: dict[str, tuple[list[str], list]] = {}
    with Progress(console=Console(stderr=True), transient=True) as bar:
        task = bar.add_task("ablations", total=sum(len(v) for *_, v in jobs))
        for title, label, seq, variants in jobs:
            cells, length = [], 0.0
            for name, config in variants.items():
                bar.update(task, description=f"{label} {name}")
                length, *metrics = score(seq, **config)
                cells.append(tuple(metrics))
                bar.advance(task)
            sections.setdefault(title, (list(variants), []))[1].append((label, length, cells))
    text = f"# SRF-Odometry ablations ({args.minutes:g} simulated minutes per map)\n\n" + "\n".join(
        table(title, columns, rows) for title, (columns, rows) in sections.items())
    if args.out:
        args.out.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
