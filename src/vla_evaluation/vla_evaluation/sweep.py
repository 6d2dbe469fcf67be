"""Every sweep's engine: independent units (a training run, an episode, a trial, a demonstration) run
as Ray tasks, on this machine or a cluster, and stream their results back to the driver.

- With no address a local Ray starts here (nothing to set up); `--ray-address HOST:PORT` joins a
  cluster started with `ray start` (docs/cluster.md). `--serial` runs the units in this process, one
  after another, without Ray: the reference a Ray run must equal, row for row.
- A unit runs on a *worker*: an object made once per Ray worker (a Ray actor) and reused for the units
  that worker gets, so that a graph, a simulator or shared data is set up once per worker, not once
  per unit. A worker that needs a ROS graph takes its own ROS domain where it runs (GraphRunner,
  vla_common.ros.domain).
- Only the driver writes results: `on_result(key, result)` is called in this process, once per unit,
  as each finishes. A worker process that dies mid-unit returns nothing; Ray restarts the worker
  (anywhere in the cluster) and runs the unit again, so it appears exactly once in the results. A unit
  that raises (or kills its worker on every try) is reported as failed and the sweep goes on; the
  caller's store is resumable, so a second run retries only what is missing.
- Units that train ask for a GPU where the cluster has one and run on the CPU where it has none.

Ray moves units and results between our own processes with its serialiser (cloudpickle); nothing is
read from a file that way.
"""
from __future__ import annotations

import argparse
import contextlib
import logging
import os
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

# A worker restarted this many times (its process died) runs the unit it held again each time; a unit
# that kills its worker more often than this fails.
RESTARTS = 3
# The local Ray's shared-object store: the experiments' demonstrations and layouts fit many times over.
LOCAL_OBJECT_STORE_BYTES = 512 * 2**20


class Worker(Protocol):
    """Made once per worker process (`make(shared)`); runs units; closed at the end of the sweep."""

    def run(self, unit: Any) -> Any: ...

    def close(self) -> None: ...


@dataclass(frozen=True)
class Engine:
    """Where a sweep runs: `address` a Ray cluster to join (None: a local Ray started here with
    `cpus` CPUs, default all of this machine's), or `serial`: here, one unit after another."""

    address: str | None = None
    cpus: int | None = None
    serial: bool = False

    def describe(self) -> str:
        if self.serial:
            return "serially in this process (no Ray)"
        if self.address:
            return f"the Ray cluster at {self.address}"
        return f"a local Ray ({self.cpus or os.cpu_count()} CPUs)"


SERIAL = Engine(serial=True)


@dataclass(frozen=True)
class Needs:
    """What one unit's worker holds: CPUs, and a GPU where the cluster has one (`gpu`: the share of
    one GPU, e.g. 0.25 to run four units on each)."""

    cpus: float = 1.0
    gpu: float = 0.0


def add_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("engine (Ray)")
    g.add_argument("--ray-address", default=None, metavar="HOST:PORT",
                   help="join this Ray cluster (default: start a local Ray on this machine)")
    g.add_argument("--ray-cpus", type=int, default=None,
                   help="CPUs of the local Ray, so at most this many units at once (default: all)")
    g.add_argument("--serial", action="store_true",
                   help="run the units one after another in this process, without Ray")


def engine_from(args: argparse.Namespace) -> Engine:
    if args.serial and args.ray_address:
        raise SystemExit("--serial and --ray-address exclude each other")
    return Engine(address=args.ray_address, cpus=args.ray_cpus, serial=bool(args.serial))


class Progress:
    """One line per finished unit, with the ETA over the whole sweep from this run's pace."""

    def __init__(self, name: str, total: int, done_before: int = 0, log: Callable[[str], None] = print):
        self.name, self.total, self.before, self.log = name, total, done_before, log
        self.done = 0
        self.t0 = time.monotonic()

    def update(self, key: str, what: str = "done") -> None:
        self.done += 1
        elapsed = time.monotonic() - self.t0
        left = self.total - self.before - self.done
        eta = elapsed / self.done * left
        self.log(f"[{self.name}] {self.before + self.done}/{self.total} {key}: {what}; "
                 f"{_duration(elapsed)} elapsed, ETA {_duration(eta)}")


def _duration(s: float) -> str:
    s = int(round(s))
    return f"{s // 3600}h{s % 3600 // 60:02d}m" if s >= 3600 else f"{s // 60}m{s % 60:02d}s"


def run_sweep(units: Sequence[tuple[str, Any]], make: Callable[[Any], Worker], *, engine: Engine,
              on_result: Callable[[str, Any], None], shared: Any = None, needs: Needs = Needs(),
              name: str = "sweep", done_before: int = 0, log: Callable[[str], None] = print) -> list[str]:
    """Run every `(key, unit)` on workers made by `make(shared)`; `on_result(key, result)` here as each
    finishes. Returns the keys of the units that failed (each logged with its error)."""
    progress = Progress(name, done_before + len(units), done_before, log)
    if not units:
        return []
    if engine.serial:
        return _serial(units, make, shared, on_result, progress, log)
    with ray_session(engine, log) as ray:
        return _on_ray(ray, units, make, shared, on_result, needs, progress, log)


def _serial(units, make, shared, on_result, progress: Progress, log) -> list[str]:
    failed = []
    worker = make(shared)
    try:
        for key, unit in units:
            try:
                result = worker.run(unit)
            except Exception as e:  # reported, and the sweep goes on (as on Ray)
                failed.append(key)
                log(f"[{progress.name}] {key} failed: {type(e).__name__}: {e}")
                continue
            on_result(key, result)
            progress.update(key)
    finally:
        worker.close()
    return failed


@contextlib.contextmanager
def ray_session(engine: Engine, log: Callable[[str], None] = print) -> Iterator[Any]:
    """Ray, started locally or joined, for the `with` block; left as found (a test's own session is
    reused and kept)."""
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")  # nothing leaves the machine
    os.environ.setdefault("RAY_DEDUP_LOGS", "0")  # every worker's "<key> started" line, as printed
    os.environ.setdefault("RAY_COLOR_PREFIX", "0")
    import ray

    if ray.is_initialized():
        yield ray
        return
    if engine.address:
        ray.init(address=engine.address, logging_level=logging.WARNING, log_to_driver=True)
    else:
        _start_local(ray, engine)
    res = ray.cluster_resources()
    log(f"[ray] {engine.describe()}: {int(res.get('CPU', 0))} CPUs, {int(res.get('GPU', 0))} GPUs, "
        f"{len([n for n in ray.nodes() if n['Alive']])} nodes")
    try:
        yield ray
    finally:
        ray.shutdown()


def _start_local(ray, engine: Engine, tries: int = 5) -> None:
    """A new local Ray of our own (`address="local"`: never one that another `ray start` left on this
    machine). Ray gives its raylet 30 s to register, hard-coded; on a loaded machine a start that
    misses it is tried again. Its workers run at the driver's niceness, not Ray's default of 15 nicer:
    beside other work (a CI run at nice 0) a sweep's graphs got next to no CPU and ran past their hang
    guard; `nice -n 10 vla_study ...` says how much a sweep yields, and means it. A start that joined
    another driver's Ray (`joined_another`) is tried again."""
    os.environ.setdefault("RAY_worker_niceness", "0")
    for attempt in range(tries):
        try:
            ray.init(address="local", num_cpus=engine.cpus or os.cpu_count(), include_dashboard=False,
                     object_store_memory=LOCAL_OBJECT_STORE_BYTES, logging_level=logging.WARNING,
                     log_to_driver=True)
        except Exception as e:  # Ray raises a bare Exception for the timeout
            if "timed out during startup" not in str(e) or attempt == tries - 1:
                raise
            ray.shutdown()
            continue
        why = joined_another(ray)
        if not why:
            return
        ray.shutdown()
        if attempt == tries - 1:
            raise RuntimeError(f"{why}; {tries} starts")


def joined_another(ray) -> str:
    """Why this driver's "local" Ray is another's ("" when it is its own: the first job of its cluster).
    Two sweeps started within a second of each other (a study in one checkout, its A/B in another)
    both asked for a new local Ray, and the second's driver came up in the first's cluster: its units
    ran in the first's workers, with the first checkout's code and models (seen 2026-12-07)."""
    job = ray.get_runtime_context().get_job_id()   # hex of the job number's bytes, little-endian
    if int.from_bytes(bytes.fromhex(job), "little") == 1:
        return ""
    return (f"this sweep's local Ray is another driver's (it is job {job} there): its units would run in "
            "that driver's workers, with their code")


def slots(resources: dict, needs: Needs, n_units: int) -> tuple[int, float]:
    """(how many workers, the GPU share each asks for): as many as the cluster's CPUs hold (and its
    GPUs, for units that want one where there are GPUs), at most one per unit."""
    n = int(resources.get("CPU", 0) // needs.cpus) if needs.cpus else n_units
    gpu = needs.gpu if needs.gpu and resources.get("GPU", 0) >= needs.gpu else 0.0
    if gpu:
        n = min(n, int(resources["GPU"] // gpu))
    return max(1, min(n, n_units)), gpu


class _Host:
    """The Ray actor around one worker: made where Ray places it, restarted there or elsewhere when
    its process dies (its unit then runs again)."""

    def __init__(self, name: str, make: Callable[[Any], Worker], shared: list) -> None:
        import ray  # in the worker

        # A graph this worker starts takes a ROS domain of its own (vla_common.ros.domain, through
        # GraphRunner), never the one the driver's environment had.
        os.environ.pop("ROS_DOMAIN_ID", None)
        # `shared` holds the reference (not the value), which Ray keeps while the driver holds it
        self.name, self.worker = name, make(ray.get(shared[0]) if shared else None)

    def run(self, key: str, unit: Any) -> Any:
        import ray

        node = ray.get_runtime_context().get_node_id()[:8]
        print(f"[{self.name}] {key} started in pid {os.getpid()} on node {node}", flush=True)
        return self.worker.run(unit)

    def close(self) -> None:
        self.worker.close()


def _on_ray(ray, units, make, shared, on_result, needs: Needs, progress: Progress, log) -> list[str]:
    from ray.exceptions import RayError

    n, gpu = slots(ray.cluster_resources(), needs, len(units))
    host = ray.remote(_Host).options(num_cpus=needs.cpus, num_gpus=gpu, max_restarts=RESTARTS,
                                     max_task_retries=RESTARTS)
    box = [ray.put(shared)] if shared is not None else []  # put once; each worker fetches it once
    workers = [host.remote(progress.name, make, box) for _ in range(n)]
    log(f"[{progress.name}] {len(units)} units on {n} workers ({needs.cpus:g} CPU"
        + (f", {gpu:g} GPU" if gpu else "") + " each)")
    queue: deque = deque(units)
    pending: dict = {}
    failed: list[str] = []

    def submit(worker) -> None:
        key, unit = queue.popleft()
        pending[worker.run.remote(key, unit)] = (worker, key)

    try:
        for w in workers[: len(queue)]:
            submit(w)
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1, timeout=1.0)  # Ctrl-C gets through
            if not ready:
                continue
            worker, key = pending.pop(ready[0])
            done = ready[0]
            try:
                result = ray.get(done)
            except RayError as e:
                failed.append(key)
                log(f"[{progress.name}] {key} failed: {_first_line(e)}")
            else:
                on_result(key, result)
                progress.update(key)
            if queue:
                submit(worker)
    finally:
        _close(ray, workers, log)
    return failed


def _close(ray, workers, log) -> None:
    from ray.exceptions import RayError

    closing = [w.close.remote() for w in workers]
    try:
        ray.get(closing, timeout=120)
    except RayError as e:
        log(f"[sweep] a worker did not close cleanly: {_first_line(e)}")
    for w in workers:
        ray.kill(w)


def _first_line(e: BaseException) -> str:
    text = str(e).strip().splitlines()
    return f"{type(e).__name__}: {text[-1] if text else ''}"
