"""The worker engine: results in the tasks' order on any engine; a killed worker costs no result."""

from __future__ import annotations

import os
import signal
from pathlib import Path

import numpy as np
import pytest

from piezofin_ros.workers import TaskError, run_tasks


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
    if k == 2:
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


def test_a_killed_worker_costs_no_result(tmp_path: Path) -> None:
    lines: list[str] = []
    marker = str(tmp_path / "killed")
    out = run_tasks(dies_once, [(k, marker) for k in range(8)], workers=2, say=lines.append)
    assert Path(marker).exists()  # the worker was killed
    assert out == [k * k for k in range(8)]
    assert any("worker process died" in line for line in lines), lines


def test_a_task_that_always_kills_its_worker_is_named_not_looped() -> None:
    with pytest.raises(TaskError, match=r"task 3/5 .*kills its worker"):
        run_tasks(always_dies, range(5), workers=2, retries=1)


def test_a_task_error_propagates_with_the_task_named() -> None:
    for workers in (1, 2):
        with pytest.raises(ValueError, match="bad plant") as info:
            run_tasks(fails, range(4), workers=workers, label=lambda k: f"plant {k}")
        assert any("task 2/4 plant 1" in n for n in info.value.__notes__)


def test_bad_settings_are_one_clear_error() -> None:
    with pytest.raises(TaskError, match="workers must be at least 1"):
        run_tasks(square, [1], workers=0)


@pytest.mark.slow
def test_on_a_local_ray_instance_the_same_results_and_a_killed_worker_is_run_again(tmp_path: Path) -> None:
    pytest.importorskip("ray", reason="ray is an optional extra (pip install 'piezofin_ros[ray]')")
    lines: list[str] = []
    reference = run_tasks(draw, range(12), workers=1)
    marker = str(tmp_path / "killed")
    on_ray = run_tasks(draw, range(12), workers=2, ray_address="local", say=lines.append)
    assert on_ray == reference
    assert lines[0].startswith("ray: local, 2 CPUs"), lines
    killed = run_tasks(dies_once, [(k, marker) for k in range(6)], workers=2, ray_address="local")
    assert Path(marker).exists()
    assert killed == [k * k for k in range(6)]
