"""`simnav batch`: seeded missions and env rollouts in parallel; local processes and Ray give the same rows."""

from __future__ import annotations

import json
import os
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest
from typer.testing import CliRunner

import simnav.cli.batch  # noqa: F401  (registers `simnav batch` on the app)
from simnav.batch import mission_jobs, rollout_jobs, run_batch, run_job
from simnav.cli import app
from simnav.errors import SimnavError
from simnav.mission.mission import MissionSettings
from simnav.sim import SimConfig

runner = CliRunner()
WORLD = "polygonal"  # one open room: short missions that need no intervention
LIDAR_ONLY = ("sensors.camera.rate_hz=0.001",)
SETTINGS = MissionSettings(targets=1, sim=SimConfig(pedestrians=1, wanderers=0))


def jobs(count: int):
    return mission_jobs(count, world=WORLD, settings=SETTINGS, first_seed=1, robot_set=LIDAR_ONLY)


@pytest.mark.slow
def test_ray_backend_gives_the_same_rows_as_local_processes():
    ray = pytest.importorskip("ray")
    batch = jobs(4)
    local = run_batch(batch, workers=2)
    ray.init(address="local", num_cpus=2, include_dashboard=False, object_store_memory=100 * 1024**2,
             log_to_driver=False)
    try:
        remote = run_batch(batch, ray_address="local")
    finally:
        ray.shutdown()
    assert local.backend == "local" and remote.backend.startswith("ray")
    assert [row["seed"] for row in local.rows] == [1, 2, 3, 4]
    assert local.outcomes() == remote.outcomes()
    assert local.summary["targets_requested"] == 4 and local.summary["success_rate"] > 0.5


def test_rollout_rows_do_not_depend_on_the_process():
    batch = rollout_jobs(2, "simnav/CorridorNav-v0", first_seed=3, env_kwargs={"people": 0, "goal_max_m": 5.0})
    here = [run_job(job) for job in reversed(batch)][::-1]
    report = run_batch(batch, workers=2)
    assert report.task == "rollout" and report.summary["jobs"] == 2
    strip = [{k: v for k, v in row.items() if k != "wall_time_s"} for row in here]
    assert report.outcomes() == strip
    assert all(row["success"] for row in report.rows)


def test_cli_batch_writes_the_report_and_every_mission(tmp_path):
    out = tmp_path / "batch"
    args = ["batch", "--missions", "2", "--workers", "2", "--world", WORLD, "--targets", "1", "--agents", "0",
            "--seed", "3", "--set", LIDAR_ONLY[0], "--keep-right", "0.25", "--out", str(out)]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    report = json.loads((out / "batch.json").read_text())
    assert report["task"] == "mission" and report["backend"] == "local" and report["workers"] == 2
    assert [row["seed"] for row in report["rows"]] == [3, 4]
    assert report["summary"]["targets_requested"] == 2
    assert (out / "rows.csv").read_text().startswith("seed,success,")
    for seed in (3, 4):
        assert (out / f"mission-{seed}" / "report.json").is_file()
        assert "keep_right_m: 0.25" in (out / f"mission-{seed}" / "mission.yaml").read_text()
    assert "targets reached" in result.output and "per mission" in result.output


def test_cli_errors_are_one_line_without_traceback(monkeypatch):
    bad_world = runner.invoke(app, ["batch", "--missions", "2", "--world", "atlantis"])
    assert bad_world.exit_code == 2 and "unknown world 'atlantis'" in bad_world.output
    bad_env = runner.invoke(app, ["batch", "--task", "rollout", "--env", "simnav/Moon-v0"])
    assert bad_env.exit_code == 2 and "unknown env 'simnav/Moon-v0'" in bad_env.output
    monkeypatch.setitem(sys.modules, "ray", None)  # as if the ray extra were not installed
    no_ray = runner.invoke(app, ["batch", "--missions", "1", "--world", WORLD, "--ray-address", "auto"])
    assert no_ray.exit_code == 2 and "pip install 'simnav[ray]'" in no_ray.output
    for result in (bad_world, bad_env, no_ray):
        assert "Traceback" not in result.output
    with pytest.raises(SimnavError, match="at least one job"):
        run_batch([])


@dataclass(frozen=True)
class _CrashOnce:
    seed: int
    marker: str


def _crash_once(job: _CrashOnce) -> dict:
    """Kills its worker process the first time any job of the batch runs (a native crash), then succeeds."""
    marker = Path(job.marker)
    if job.seed == 1 and not marker.exists():
        marker.touch()
        os._exit(134)
    return {"seed": job.seed, "pid_ok": True}


def test_a_worker_that_dies_does_not_lose_the_batch(tmp_path):
    from simnav.batch.runner import LOCAL_RESTARTS, _run_local

    jobs = [_CrashOnce(seed, str(tmp_path / "crashed")) for seed in range(4)]
    rows = _run_local(jobs, 2, None, function=_crash_once)
    assert [row["seed"] for row in rows] == [0, 1, 2, 3]
    assert (tmp_path / "crashed").exists()
    # a job that kills every worker it runs in fails the batch with one clear error
    with pytest.raises(SimnavError, match=r"seed 1 failed: worker processes died 3 times"):
        _run_local([_CrashOnce(1, str(tmp_path / "never"))], 1, None, function=_crash_always)
    assert LOCAL_RESTARTS == 2


def _crash_always(job: _CrashOnce) -> dict:
    os._exit(134)


def _children(pid: int) -> list[int]:
    """Live worker processes (``spawn_main``) whose parent is ``pid`` (Linux /proc)."""
    found = []
    for entry in Path("/proc").iterdir():
        status = _status(int(entry.name)) if entry.name.isdigit() else None
        if status is not None and status[0] != "Z" and int(status[1]) == pid:
            try:
                if b"spawn_main" in (entry / "cmdline").read_bytes():
                    found.append(int(entry.name))
            except OSError:
                continue
    return found


def _status(pid: int) -> list[str] | None:
    """The fields of /proc/PID/stat after the command name (state, parent pid, ...), None when it is gone."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None


def _alive(pid: int) -> bool:
    """Whether process ``pid`` exists and is not a zombie."""
    status = _status(pid)
    return status is not None and status[0] != "Z"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_workers_stop_when_the_batch_process_is_killed():
    import signal
    import subprocess
    import time

    from simnav.batch.runner import PARENT_POLL_S

    code = "import time; from simnav.batch.runner import _run_local; _run_local([60.0, 60.0], 2, None, time.sleep)"
    batch = subprocess.Popen([sys.executable, "-c", code])
    workers: list[int] = []
    try:
        deadline = time.monotonic() + 60.0
        while len(workers) < 2 and time.monotonic() < deadline:
            time.sleep(0.2)
            workers = _children(batch.pid)
        assert len(workers) == 2  # both started their 60 s job
        batch.send_signal(signal.SIGTERM)  # no clean-up runs in the batch process
        batch.wait(timeout=10)
        deadline = time.monotonic() + 5.0 + 2 * PARENT_POLL_S
        while any(_alive(pid) for pid in workers) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not any(_alive(pid) for pid in workers)
    finally:
        for pid in [batch.pid, *workers]:
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)
