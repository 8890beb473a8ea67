"""Independent tasks on worker processes: this machine's by default, a Ray cluster when given one.

The benchmarks and the paper-facts diagnosis are many independent, deterministic tasks (a plant
and a seed, a dataset, a hypothesis).  :func:`run_tasks` runs them and returns the results **in
the order of the tasks**, whatever order they finish in, so a table built from them is the same on
one worker, on two, and on a cluster, for a fixed seed::

    results = run_tasks(score_plant, cases, workers=2)               # local worker processes
    results = run_tasks(score_plant, cases, ray_address="local")      # a Ray instance on this machine
    results = run_tasks(score_plant, cases, ray_address="10.0.0.5:6379")  # a running Ray cluster

Engines:

* ``workers == 1`` and no address: in this process, one task after another (no pickling, so a
  debugger and a profiler see the task).
* local (the default, ``workers`` processes of :class:`concurrent.futures.ProcessPoolExecutor`):
  a worker that dies (SIGKILL, the kernel's out-of-memory killer, a segfault) breaks the pool; the
  results already in are kept, a new pool is started and every task not yet returned is run again.
  A task that was running each time ``retries + 1`` pools broke is the likely killer: it stops the
  run with :class:`TaskError` naming it, rather than looping.
* Ray (``ray_address``; ``pip install 'piezofin_ros[ray]'``): each task is a Ray task with
  ``max_retries=retries``, so a worker or node that dies has its tasks run again by Ray itself.
  ``"local"`` starts a Ray instance on this machine bound to loopback with ``workers`` CPUs; any
  other value is a cluster's address (``"auto"``, ``"host:6379"``, ``"ray://host:10001"``), whose
  nodes need numpy/scipy; the package itself is shipped to them with the job
  (``runtime_env.py_modules``).  Without Ray installed, the local workers are used and that is said
  once.  Ray's usage statistics stay off.

Progress: one line per finished task through ``say`` (``[k/n] label (elapsed s, about r s left)``).
Exceptions raised by a task are not retried (a deterministic task fails the same way again): they
propagate, with the task's label added as a note.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any, TypeVar

from .errors import PiezofinError

T = TypeVar("T")
R = TypeVar("R")

#: Ray's usage statistics would be sent beyond this machine: off, whatever the environment says.
_RAY_ENV = {"RAY_USAGE_STATS_ENABLED": "0"}


class TaskError(PiezofinError, RuntimeError):
    """The worker engine cannot run a task (one that kills its worker every time, a Ray that cannot
    start or be reached)."""


def default_workers() -> int:
    """One worker per core this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


def _elapsed(t0: float, done: int, total: int) -> str:
    dt = time.perf_counter() - t0
    if done < total and done > 0:
        return f"{dt:.0f} s, about {dt / done * (total - done):.0f} s left"
    return f"{dt:.0f} s"


def run_tasks(
    fn: Callable[[T], R],
    items: Sequence[T],
    *,
    workers: int | None = None,
    ray_address: str | None = None,
    say: Callable[[str], None] | None = None,
    label: Callable[[T], str] | None = None,
    retries: int = 2,
) -> list[R]:
    """``[fn(item) for item in items]`` on worker processes, in the items' order (module docstring).

    ``fn`` and the items must be picklable (a module-level function); ``label(item)`` names a task
    in the progress lines and errors (default: its index)."""
    items = list(items)
    say = say or (lambda _m: None)
    name = label or (lambda _i: "")
    workers = default_workers() if workers is None else int(workers)
    if workers < 1:
        raise TaskError(f"workers must be at least 1, not {workers}")
    if retries < 0:
        raise TaskError(f"retries must be 0 or more, not {retries}")
    if ray_address:
        ray = _import_ray(say)
        if ray is not None:
            return _run_ray(ray, fn, items, workers, ray_address, say, name, retries)
    if workers == 1 or len(items) <= 1:
        return _run_here(fn, items, say, name)
    return _run_local(fn, items, workers, say, name, retries)


def _tag(t: str) -> str:
    return f" {t}" if t else ""


def _run_here(
    fn: Callable[[T], R], items: list[T], say: Callable[[str], None], name: Callable[[T], str]
) -> list[R]:
    t0 = time.perf_counter()
    out = []
    for k, item in enumerate(items):
        try:
            out.append(fn(item))
        except Exception as e:
            e.add_note(f"in task {k + 1}/{len(items)}{_tag(name(item))}")
            raise
        say(f"[{k + 1}/{len(items)}]{_tag(name(item))} ({_elapsed(t0, k + 1, len(items))})")
    return out


def _run_local(
    fn: Callable[[T], R],
    items: list[T],
    workers: int,
    say: Callable[[str], None],
    name: Callable[[T], str],
    retries: int,
) -> list[R]:
    t0 = time.perf_counter()
    results: dict[int, R] = {}
    suspect = [0] * len(items)  # pools that broke while this task was running
    while len(results) < len(items):
        todo = [k for k in range(len(items)) if k not in results]
        pool = ProcessPoolExecutor(min(workers, len(todo)))
        futures: dict[Future[R], int] = {pool.submit(fn, items[k]): k for k in todo}
        broken = False
        running: set[int] = set()  # the tasks in the workers' hands when the last wait began
        try:
            pending = set(futures)
            while pending and not broken:
                running = {futures[f] for f in pending if f.running()}
                done, pending = wait(pending, return_when=FIRST_COMPLETED)
                for fut in done:
                    k = futures[fut]
                    try:
                        results[k] = fut.result()
                    except BrokenProcessPool:
                        broken = True
                        continue
                    except Exception as e:
                        e.add_note(f"in task {k + 1}/{len(items)}{_tag(name(items[k]))}")
                        raise
                    say(
                        f"[{len(results)}/{len(items)}]{_tag(name(items[k]))} "
                        f"({_elapsed(t0, len(results), len(items))})"
                    )
            if broken:
                for fut, k in futures.items():  # finished before the pool broke: kept
                    if k not in results and fut.done() and not fut.cancelled() and fut.exception() is None:
                        results[k] = fut.result()
                lost = [k for k in futures.values() if k not in results]
                for k in [k for k in lost if k in running] or lost:
                    suspect[k] += 1
                worst = max(lost, key=lambda k: suspect[k])
                if suspect[worst] > retries:
                    raise TaskError(
                        f"task {worst + 1}/{len(items)}{_tag(name(items[worst]))} was running each of the "
                        f"{suspect[worst]} times a worker died: it kills its worker; not run again"
                    )
                say(
                    f"a worker process died: {len(lost)} unfinished task(s) run again on new workers "
                    f"({len(results)} kept)"
                )
        finally:
            pool.shutdown(wait=not broken, cancel_futures=True)
    return [results[k] for k in range(len(items))]


_said_no_ray = False


def _import_ray(say: Callable[[str], None]) -> Any:
    global _said_no_ray
    try:
        import ray  # optional: pip install 'piezofin_ros[ray]'
    except ImportError:
        if not _said_no_ray:
            say("ray is not installed (pip install 'piezofin_ros[ray]'): using local worker processes")
            _said_no_ray = True
        return None
    return ray


def _run_ray(
    ray: Any,
    fn: Callable[[T], R],
    items: list[T],
    workers: int,
    address: str,
    say: Callable[[str], None],
    name: Callable[[T], str],
    retries: int,
) -> list[R]:
    os.environ.update(_RAY_ENV)  # read by ray.init and by the processes it starts
    package = str(Path(__file__).resolve().parent)
    started_here = not ray.is_initialized()
    if started_here:
        kwargs: dict[str, Any] = {
            "runtime_env": {"py_modules": [package], "env_vars": dict(_RAY_ENV)},
            "include_dashboard": False,
            "log_to_driver": False,
            "configure_logging": False,
        }
        if address == "local":
            kwargs.update(num_cpus=workers, _node_ip_address="127.0.0.1")
        else:
            kwargs["address"] = address
        try:
            ray.init(**kwargs)
        except Exception as e:  # ray's own errors vary with the version: ConnectionError, RuntimeError
            raise TaskError(f"cannot start or reach Ray at {address!r}: {e}") from e
        say(f"ray: {address}, {int(ray.cluster_resources().get('CPU', 0))} CPUs")
    try:
        remote = ray.remote(max_retries=retries, num_cpus=1)(fn)
        t0 = time.perf_counter()
        refs = [remote.remote(item) for item in items]
        index = {ref: k for k, ref in enumerate(refs)}
        pending = list(refs)
        done_n = 0
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            for ref in ready:
                k = index[ref]
                try:
                    ray.get(ref)
                except Exception as e:
                    cause = getattr(e, "cause", None)  # a RayTaskError carries the task's own exception
                    err = cause if isinstance(cause, Exception) else e
                    err.add_note(f"in task {k + 1}/{len(items)}{_tag(name(items[k]))} (on Ray)")
                    raise err from None
                done_n += 1
                say(f"[{done_n}/{len(items)}]{_tag(name(items[k]))} ({_elapsed(t0, done_n, len(items))})")
        return list(ray.get(refs))
    finally:
        if started_here:
            ray.shutdown()


def run_parsed(
    fn: Callable[[T], R], items: Sequence[T], args: Any, label: Callable[[T], str], prefix: str = ""
) -> list[R]:
    """:func:`run_tasks` as a command's ``--workers`` and ``--ray`` ask (:func:`add_arguments`), its
    progress lines on standard error after ``prefix``."""
    return run_tasks(
        fn,
        items,
        workers=args.workers,
        ray_address=args.ray,
        say=lambda line: print(f"{prefix}{line}", file=sys.stderr, flush=True),
        label=label,
    )


def add_arguments(parser: Any) -> None:
    """``--workers N`` and ``--ray ADDRESS`` for a command that runs independent tasks."""
    parser.add_argument(
        "--workers",
        type=int,
        default=default_workers(),
        help="worker processes on this machine (default: one per core; 1: in this process)",
    )
    parser.add_argument(
        "--ray",
        metavar="ADDRESS",
        default=None,
        help="run the tasks on Ray: 'local' (a Ray instance on this machine, --workers CPUs) or a "
        "cluster's address ('auto', 'host:6379', 'ray://host:10001'); needs pip install 'piezofin_ros[ray]'",
    )
