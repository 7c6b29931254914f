"""scripts/intervention_summary.py: what the robot did before each intervention, and its turning over whole missions."""

from __future__ import annotations

import csv
import json
import math
import subprocess
import sys
from pathlib import Path

from simnav.mission.mission import NAV_LOG_COLUMNS

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "intervention_summary.py"


def _write_mission(folder: Path, world: str | None = None, xy_m: tuple[float, float] | None = None) -> None:
    """40 s at 10 Hz: 10 s driving along +x at 0.5 m/s, 20 s turning on the spot at 0.5 rad/s, 10 s waiting; then an
    intervention sets the robot down 5 m away. ``world``: the report names it; ``xy_m``: where the intervention is
    logged (default where the robot stands)."""
    rows = []
    x, yaw = 0.0, 0.0
    for k in range(401):
        t = 0.1 * k
        if t < 10.0:
            v, w, state = 0.5, 0.0, "navigating"
        elif t < 30.0:
            v, w, state = 0.0, 0.5, "navigating"
        else:
            v, w, state = 0.0, 0.0, "waiting"
        rows.append([t, x, 0.0, math.atan2(math.sin(yaw), math.cos(yaw)), v, w, state, 1, "alpha", 3, 1.0, 1.0])
        x, yaw = x + 0.1 * v, yaw + 0.1 * w
    rows.append([40.1, x + 5.0, 0.0, 0.0, 0.0, 0.0, "navigating", 2, "C", 60, 1.0, 1.0])  # set down elsewhere
    folder.mkdir(parents=True)
    with (folder / "navigation.csv").open("w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(NAV_LOG_COLUMNS)
        writer.writerows(rows)
    at = xy_m or (x, 0.0)
    log = [{"time_s": 40.05, "target": 0, "x_m": at[0], "y_m": at[1], "moved_to_node": 3}]
    report = {"intervention_log": log} | ({"world": world} if world else {})
    (folder / "report.json").write_text(json.dumps(report))


def test_the_summary_counts_turning_in_the_window_and_over_whole_missions(tmp_path) -> None:
    _write_mission(tmp_path / "batch" / "mission-1")
    out = subprocess.run([sys.executable, str(SCRIPT), str(tmp_path / "batch")], capture_output=True, text=True,
                         check=True, env={"COLUMNS": "200", "PATH": ""}).stdout
    # the 30 s window (10.05-40.05 s): 19.9 s turning at 0.5 rad/s, 570 deg, then waiting; no drive
    assert "1 interventions in 1 missions: 1 turning" in out
    assert "│ 0.00     │ 570 " in out
    # whole mission: 5 m driven (the 5 m jump of the intervention is not), 1.6 turns, 20 s on the spot
    assert "whole missions: 5.0 m driven, 2 full turns, 20 s turning on the spot" in out
    assert "0 within 0.6 m of a door leaf standing open" in out  # no world named: no distance


def test_interventions_beside_an_open_door_leaf_are_counted(tmp_path) -> None:
    # the office's south-east room: its leaf stands open along x = 16.43 m from y = -1.1 to -2.1 m (4 cm thick)
    _write_mission(tmp_path / "batch" / "mission-1", world="office", xy_m=(16.0, -1.5))
    _write_mission(tmp_path / "batch" / "mission-2", world="office", xy_m=(10.0, 0.0))  # mid-corridor
    out = subprocess.run([sys.executable, str(SCRIPT), str(tmp_path / "batch")], capture_output=True, text=True,
                         check=True, env={"COLUMNS": "200", "PATH": ""}).stdout
    assert "│ 0.41 " in out
    assert "1 within 0.6 m of a door leaf standing open" in out


def test_a_folder_without_reports_is_one_clear_error(tmp_path) -> None:
    result = subprocess.run([sys.executable, str(SCRIPT), str(tmp_path)], capture_output=True, text=True)
    assert result.returncode == 2
    assert "no report.json" in result.stdout
    assert "Traceback" not in result.stderr
