"""The aggregated report of a batch: a summary over all jobs and one row per job, as ``batch.json``/``rows.csv``."""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import simnav
from simnav.batch.jobs import TIMING_FIELDS, Job, MissionJob
from simnav.io import json_finite

INCIDENT_KINDS = ("static", "door", "people", "robots")


@dataclass
class BatchReport:
    """What a batch did.

    Attributes:
        task: ``"mission"`` or ``"rollout"``.
        backend: ``"local"`` or ``"ray (<address>)"``.
        workers: worker processes (local) or tasks in flight at most (Ray).
        wall_time_s: wall time of the whole batch, s.
        summary: aggregates (see :meth:`from_rows`).
        rows: one dict per job, in job order (seed first).
    """

    task: str
    backend: str
    workers: int
    wall_time_s: float
    summary: dict[str, Any] = field(default_factory=dict)
    rows: list[dict[str, Any]] = field(default_factory=list)

    @classmethod
    def from_rows(cls, jobs: Sequence[Job], rows: list[dict[str, Any]], backend: str, workers: int,
                  wall_time_s: float) -> BatchReport:
        """Aggregate the rows.

        Missions: targets reached / requested (``success_rate``), missions with every target reached, incidents by
        kind, interventions, distance and simulated time. Rollouts: episodes reached (``success_rate``),
        collisions, time-outs, mean return and steps.
        """
        task = "mission" if isinstance(jobs[0], MissionJob) else "rollout"
        summary = _mission_summary(rows) if task == "mission" else _rollout_summary(rows)
        summary["jobs"] = len(rows)
        summary["sim_time_per_wall_s"] = _sim_time(rows, task) / wall_time_s if wall_time_s > 0 else math.inf
        return cls(task, backend, workers, wall_time_s, summary, rows)

    def outcomes(self) -> list[dict[str, Any]]:
        """The rows without their wall-clock fields: what must agree between backends for the same seeds."""
        return [{k: v for k, v in row.items() if k not in TIMING_FIELDS} for row in self.rows]

    def to_json(self) -> str:
        data = {"simnav_version": simnav.__version__, **asdict(self)}
        return json.dumps(json_finite(data), indent=2)

    def write(self, out_dir: Path) -> None:
        """``batch.json`` (summary and rows) and ``rows.csv`` into ``out_dir``."""
        out_dir.mkdir(parents=True, exist_ok=True)
        (out_dir / "batch.json").write_text(self.to_json() + "\n")
        with (out_dir / "rows.csv").open("w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(self.rows[0]))
            writer.writeheader()
            writer.writerows(self.rows)


def _mission_summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    requested = sum(r["targets_requested"] for r in rows)
    reached = sum(r["targets_reached"] for r in rows)
    clearances = [r["min_clearance_m"] for r in rows if r["min_clearance_m"] is not None]
    return {
        "success_rate": reached / requested if requested else 0.0,
        "targets_reached": reached,
        "targets_requested": requested,
        "missions_all_reached": sum(bool(r["success"]) for r in rows),
        "incidents": sum(r["incidents"] for r in rows),
        **{f"incidents_{kind}": sum(r[f"incidents_{kind}"] for r in rows) for kind in INCIDENT_KINDS},
        "interventions": sum(r["interventions"] for r in rows),
        "distance_m": sum(r["distance_m"] for r in rows),
        "sim_time_s": sum(r["duration_s"] for r in rows),
        "min_clearance_m": min(clearances) if clearances else None,
    }


def _rollout_summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    n = len(rows)
    return {
        "success_rate": sum(bool(r["success"]) for r in rows) / n,
        "episodes_reached": sum(bool(r["success"]) for r in rows),
        "collisions": sum(bool(r["collision"]) for r in rows),
        "timeouts": sum(bool(r["truncated"]) for r in rows),
        "mean_return": sum(r["episode_return"] for r in rows) / n,
        "mean_steps": sum(r["steps"] for r in rows) / n,
        "sim_time_s": sum(r["sim_time_s"] for r in rows),
    }


def _sim_time(rows: list[dict[str, Any]], task: str) -> float:
    return sum(r["duration_s" if task == "mission" else "sim_time_s"] for r in rows)


