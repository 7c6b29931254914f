"""Running many jobs in parallel: local worker processes by default, Ray tasks on a cluster.

Both backends call the same :func:`~simnav.batch.jobs.run_job` on the same jobs, so the same seeds give the same
rows; only the wall-clock fields differ. Ray is optional (``pip install 'simnav[ray]'``) and imported only for the
Ray backend.

Ray 2.60 clusters use token authentication: the token is read from ``RAY_AUTH_TOKEN``, ``RAY_AUTH_TOKEN_PATH`` or
``~/.ray/auth_token`` (written by ``ray start`` on the head node). For an explicit ``HOST:PORT`` address the driver
must also run with ``RAY_AUTH_MODE=token``; it is set here when a token is available and the variable is unset.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any

from simnav.batch.jobs import Job, run_job
from simnav.batch.report import BatchReport
from simnav.errors import SimnavError

log = logging.getLogger(__name__)

Progress = Callable[[int, int, dict[str, Any]], None]
"""Called after every finished job with (jobs done, jobs in all, the job's row)."""

RAY_INSTALL_HINT = "pip install 'simnav[ray]'"
LOCAL_RESTARTS = 2
"""Fresh pools a local batch starts after worker processes died (see :func:`_run_local`)."""
PARENT_POLL_S = 1.0
"""A local worker process checks this often whether the batch that started it is still there, s."""


def run_batch(jobs: Sequence[Job], workers: int | None = None, ray_address: str | None = None,
              progress: Progress | None = None) -> BatchReport:
    """Run ``jobs`` in parallel and aggregate their rows (in job order).

    Args:
        jobs: missions or env rollouts (:class:`~simnav.batch.jobs.MissionJob`, :class:`~simnav.batch.jobs.RolloutJob`).
        workers: local worker processes (default: one per CPU, at most one per job); with Ray, the most tasks in
            flight at once (default: the cluster's CPUs).
        ray_address: None for local processes; ``"auto"`` (a cluster this machine belongs to), ``"HOST:PORT"``
            (a cluster's head) or ``"local"`` (a private Ray instance started here, ``workers`` CPUs). When Ray is
            already initialised in this process, that connection is used whatever the address.
        progress: called after every finished job.

    Raises:
        SimnavError: no jobs, fewer than 1 worker, Ray missing or unreachable, or a job that failed (its error).
    """
    if not jobs:
        raise SimnavError("a batch needs at least one job (--missions >= 1)")
    if workers is not None and workers < 1:
        raise SimnavError(f"workers must be >= 1, got {workers}")
    started = time.perf_counter()
    if ray_address is None:
        count = workers or min(len(jobs), os.cpu_count() or 1)
        rows = _run_local(jobs, count, progress)
        backend = "local"
    else:
        rows, count = _run_ray(jobs, workers, ray_address, progress)
        backend = f"ray ({ray_address})"
    return BatchReport.from_rows(jobs, rows, backend=backend, workers=count, wall_time_s=time.perf_counter() - started)


# ------------------------------------------------------------------------------------------------------- local
def _run_local(jobs: Sequence[Job], workers: int, progress: Progress | None,
               function: Callable[[Job], dict[str, Any]] = run_job) -> list[dict[str, Any]]:
    """Worker processes started with ``spawn`` (safe with GL contexts and threads in this process).

    A worker that dies (a crash in native code, killed for memory) breaks the pool and every job then in flight;
    those jobs run again in a fresh pool, up to ``LOCAL_RESTARTS`` times per batch (the rows of a job do not depend
    on the process it runs in), so one crash does not lose the batch. A worker whose batch process is gone (killed,
    e.g. by a scheduler's SIGTERM, which skips all clean-up) exits within ``PARENT_POLL_S`` instead of running its
    queued jobs on and writing their folders into ``--out``."""
    rows: list[dict[str, Any] | None] = [None] * len(jobs)
    todo = list(range(len(jobs)))
    for _ in range(LOCAL_RESTARTS + 1):
        todo = _run_pool(jobs, todo, workers, progress, function, rows)
        if not todo:
            return rows  # type: ignore[return-value]
        log.warning("a worker process died; running %d unfinished job(s) again in a fresh pool", len(todo))
    raise SimnavError(f"{_describe(jobs[todo[0]])} failed: worker processes died {LOCAL_RESTARTS + 1} times "
                      f"while it ran")


def _run_pool(jobs: Sequence[Job], todo: list[int], workers: int, progress: Progress | None,
              function: Callable[[Job], dict[str, Any]], rows: list[dict[str, Any] | None]) -> list[int]:
    """Run the jobs ``todo`` in one pool, filling ``rows``; returns the jobs left unfinished by a dead worker."""
    context = multiprocessing.get_context("spawn")
    lost: list[int] = []
    with ProcessPoolExecutor(max_workers=workers, mp_context=context, initializer=_exit_with_parent,
                             initargs=(os.getpid(),)) as pool:
        pending = {pool.submit(function, jobs[k]): k for k in todo}
        try:
            while pending:
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
                for future in done:
                    k = pending.pop(future)
                    if isinstance(future.exception(), BrokenProcessPool):
                        lost.append(k)
                        continue
                    rows[k] = _result(future.result, jobs[k])
                    _report(progress, sum(r is not None for r in rows), len(jobs), rows[k])
        except BaseException:  # a failed job or Ctrl-C: drop the jobs not started yet
            pool.shutdown(wait=False, cancel_futures=True)
            raise
    return sorted(lost)


def _exit_with_parent(parent_pid: int) -> None:
    """In a worker process: a daemon thread that ends the process once its parent is no longer ``parent_pid``."""

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(PARENT_POLL_S)
        os._exit(1)

    threading.Thread(target=watch, name="simnav-parent-watch", daemon=True).start()


# --------------------------------------------------------------------------------------------------------- Ray
def _run_ray(jobs: Sequence[Job], workers: int | None, address: str,
             progress: Progress | None) -> tuple[list[dict[str, Any]], int]:
    """One Ray task per job (1 CPU each), at most ``workers`` (default: the cluster's CPUs) in flight."""
    use_auth_token(address)
    ray = import_ray()
    started_here = not ray.is_initialized()
    if started_here:
        connect_ray(address, workers)
    try:
        task = ray.remote(num_cpus=1, max_retries=1)(run_job)
        window = workers or max(1, int(ray.cluster_resources().get("CPU", 1)))
        rows: list[dict[str, Any] | None] = [None] * len(jobs)
        in_flight: dict[Any, int] = {}
        next_job, done_count = 0, 0
        while done_count < len(jobs):
            while next_job < len(jobs) and len(in_flight) < window:
                in_flight[task.options(name=f"simnav-job-{next_job}").remote(jobs[next_job])] = next_job
                next_job += 1
            ready, _ = ray.wait(list(in_flight), num_returns=1)
            for ref in ready:
                k = in_flight.pop(ref)
                rows[k] = _result(lambda ref=ref: ray.get(ref), jobs[k])
                done_count += 1
                _report(progress, done_count, len(jobs), rows[k])
        return rows, window  # type: ignore[return-value]
    finally:
        if started_here:
            ray.shutdown()


def import_ray():
    """The ``ray`` module, or one clear error naming the extra to install."""
    try:
        import ray
    except ImportError:
        raise SimnavError(f"the Ray backend (--ray-address) needs Ray: {RAY_INSTALL_HINT}") from None
    return ray


def connect_ray(address: str, workers: int | None = None) -> None:
    """``ray.init`` for ``address`` (``"local"`` starts a private instance with ``workers`` CPUs), with the token
    authentication of Ray >= 2.60 and one clear error when the cluster cannot be reached."""
    use_auth_token(address)
    ray = import_ray()
    kwargs: dict[str, Any] = {"log_to_driver": False, "logging_level": logging.WARNING}
    if address == "local":
        kwargs.update(num_cpus=workers, include_dashboard=False)
    try:
        ray.init(address=address, **kwargs)
    except Exception as err:  # ConnectionError, AuthenticationError, ValueError on a malformed address, ...
        hint = {"auto": "start one with `ray start --head` (or use --ray-address local)",
                "local": "a private Ray instance could not start here"}.get(
            address, "check the address and the auth token (RAY_AUTH_TOKEN, RAY_AUTH_TOKEN_PATH or ~/.ray/auth_token)")
        message = str(err).strip().rstrip(".")
        raise SimnavError(f"cannot connect to Ray at '{address}': {type(err).__name__}: {message}; {hint}") from None


def use_auth_token(address: str) -> None:
    """For an explicit ``HOST:PORT``, send the auth token (``RAY_AUTH_MODE=token``) when one is available and the
    mode is not set. Ray reads the mode when it is imported: this must run before ``import ray``."""
    if address not in ("auto", "local") and "RAY_AUTH_MODE" not in os.environ and _auth_token_available():
        os.environ["RAY_AUTH_MODE"] = "token"


def _auth_token_available() -> bool:
    return bool(os.environ.get("RAY_AUTH_TOKEN") or os.environ.get("RAY_AUTH_TOKEN_PATH")
                or (Path.home() / ".ray" / "auth_token").is_file())


# ----------------------------------------------------------------------------------------------------- helpers
def _result(get: Callable[[], dict[str, Any]], job: Job) -> dict[str, Any]:
    """The job's row, or one error naming the job (the worker's own error message kept)."""
    try:
        return get()
    except SimnavError as err:
        raise SimnavError(f"{_describe(job)}: {err}") from None
    except Exception as err:
        raise SimnavError(f"{_describe(job)} failed: {type(err).__name__}: {err}") from err


def _describe(job: Job) -> str:
    kind = "mission" if hasattr(job, "settings") else "rollout"
    return f"{kind} with seed {job.seed}"


def _report(progress: Progress | None, done: int, total: int, row: dict[str, Any]) -> None:
    if progress is not None:
        progress(done, total, row)
