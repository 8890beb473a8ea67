"""The worker engine: results in the tasks' order on any engine; a killed worker costs no result."""

from __future__ import annotations

import argparse
import importlib.util
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import psutil
import pytest

from piezofin_ros.workers import TaskError, add_arguments, run_parsed, run_tasks


def draw(seed: int) -> float:
    """A deterministic task that takes a little while (a worker's order of finishing varies)."""
    rng = np.random.default_rng(seed)
    return float(sum(np.sort(rng.normal(size=20_000 * (1 + seed % 5))).cumsum()[-1] for _ in range(5)))


def dies_once(arg: tuple[int, str]) -> int:
    """SIGKILLs its own worker process the first time it runs (a marker file remembers)."""
    k, marker = arg
    if k == 3 and not os.path.exists(marker):
        Path(marker).write_text(str(os.getpid()))
        os.kill(os.getpid(), signal.SIGKILL)
    return k * k


def always_dies(k: int) -> int:
    time.sleep(0.02)  # the others are in the workers' hands too
    if k == 6:
        os.kill(os.getpid(), signal.SIGKILL)
    return k


def fails(k: int) -> int:
    if k == 1:
        raise ValueError("bad plant")
    return k


def square(k: int) -> int:
    return k * k


def test_results_come_in_the_tasks_order_on_one_and_two_workers() -> None:
    lines: list[str] = []
    one = run_tasks(draw, range(12), workers=1)
    two = run_tasks(draw, range(12), workers=2, say=lines.append, label=lambda s: f"seed {s}")
    assert two == one  # bit for bit: the same tasks, the same order
    assert len(lines) == 12 and lines[-1].startswith("[12/12] seed ")
    assert all("s" in line for line in lines)


def test_a_command_runs_its_tasks_as_its_options_ask(capsys: pytest.CaptureFixture[str]) -> None:
    """``run_parsed``: ``--workers`` and ``--ray`` as :func:`add_arguments` parses them, progress on
    standard error after the command's prefix, each task named by its label."""
    ap = argparse.ArgumentParser()
    add_arguments(ap)
    for argv in (["--workers", "1"], ["--workers", "2"]):
        done = run_parsed(abs, [-3, -1, -2], ap.parse_args(argv), lambda x: f"task {x}", prefix="  b: ")
        assert done == [3, 1, 2]
        err = capsys.readouterr().err
        assert "  b: [3/3] task " in err and err.count("\n") == 3, err


def test_a_killed_worker_costs_no_result(tmp_path: Path) -> None:
    lines: list[str] = []
    marker = str(tmp_path / "killed")
    out = run_tasks(dies_once, [(k, marker) for k in range(8)], workers=2, say=lines.append)
    assert Path(marker).exists()  # the worker was killed
    assert out == [k * k for k in range(8)]
    assert any("worker process died" in line for line in lines), lines


def test_a_task_that_always_kills_its_worker_is_named_not_looped() -> None:
    with pytest.raises(TaskError, match=r"task 7/10 .*kills its worker"):
        run_tasks(always_dies, range(10), workers=2, retries=1)


def test_a_task_error_propagates_with_the_task_named() -> None:
    for workers in (1, 2):
        with pytest.raises(ValueError, match="bad plant") as info:
            run_tasks(fails, range(4), workers=workers, label=lambda k: f"plant {k}")
        assert any("task 2/4 plant 1" in n for n in info.value.__notes__)


def test_bad_settings_are_one_clear_error() -> None:
    with pytest.raises(TaskError, match="workers must be at least 1"):
        run_tasks(square, [1], workers=0)


@pytest.mark.slow
@pytest.mark.exclusive  # (Ray waits 30 s of wall time, hard-coded, for its raylet: beside two CPU-bound
# tests it timed out once, "The current node timed out during startup", 2026-11-25)
def test_on_a_local_ray_instance_the_same_results_and_a_killed_worker_is_run_again(tmp_path: Path) -> None:
    ray = pytest.importorskip("ray", reason="ray is an optional extra (pip install 'piezofin_ros[ray]')")
    reference = run_tasks(draw, range(12), workers=1)
    marker = str(tmp_path / "killed")
    ray.init(num_cpus=2, include_dashboard=False, _node_ip_address="127.0.0.1", log_to_driver=False)
    try:  # one instance for both runs (run_tasks uses a Ray it finds running)
        assert run_tasks(draw, range(12), ray_address="local") == reference
        killed = run_tasks(dies_once, [(k, marker) for k in range(6)], ray_address="local")
    finally:
        ray.shutdown()
    assert Path(marker).exists()
    assert killed == [k * k for k in range(6)]


ROOT = Path(__file__).resolve().parents[1]
BENCH = [
    "benchmarks/bench_controller.py",
    "--fins", "M8528-P1",
    "--seeds", "1",
    "--plants", "nominal", "loss", "combined",
    "--no-drift",
    "--plot", "",
]  # fmt: skip


def _table(stdout: str) -> str:
    """The benchmark's table without its wall-time line."""
    return "\n".join(line for line in stdout.splitlines() if not re.fullmatch(r"\(\d+ s\)", line))


def _bench(*extra: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, *BENCH, *extra],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
        stdin=subprocess.DEVNULL,
        env={**os.environ, "RAY_USAGE_STATS_ENABLED": "0"},
    )


@pytest.mark.slow
def test_a_benchmark_gives_the_same_table_on_one_two_workers_ray_and_with_a_worker_killed() -> None:
    """`bench_controller.py` as a user runs it (6 tasks): the table is the same on one worker, on two
    with one of them SIGKILLed mid-run, and on a local Ray instance."""
    one = _bench("--workers", "1")
    assert one.returncode == 0, one.stderr
    assert "ours" in one.stdout and "[6/6]" in one.stderr
    # on two workers, one of them killed once the first task is in: its task is run again, and the
    # table is the one-worker table
    proc = subprocess.Popen(
        [sys.executable, *BENCH, "--workers", "2"],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        stdin=subprocess.DEVNULL,
    )
    assert proc.stderr is not None
    err = []
    for line in proc.stderr:
        err.append(line)
        if "[1/6]" in line:
            break
    workers = [p for p in psutil.Process(proc.pid).children() if "python" in p.name()]
    assert workers, "no worker processes"
    workers[0].send_signal(signal.SIGKILL)
    out, rest = proc.communicate(timeout=600)
    err.append(rest)
    assert proc.returncode == 0, "".join(err)
    assert "a worker process died" in "".join(err)
    assert _table(out) == _table(one.stdout)

    if importlib.util.find_spec("ray") is None:
        pytest.skip("ray is an optional extra (pip install 'piezofin_ros[ray]'): the Ray run is skipped")
    on_ray = _bench("--workers", "2", "--ray", "local")
    assert on_ray.returncode == 0, on_ray.stderr
    assert "ray: local, 2 CPUs" in on_ray.stderr
    assert _table(on_ray.stdout) == _table(one.stdout)
