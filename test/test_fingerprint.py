"""``tools/fingerprint.py``, the behaviour check a refactoring of the optimiser or the fish loop is
held to (issue 40: the optimiser's split into rooms was identical on all ten scenarios): run as a
developer types it against a tree, it compares in another process; the same tree gives the same
hashes (the check is worth nothing if a run is not reproducible), and a tree that is no project is
refused with one line."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_the_fingerprint_of_a_tree_against_itself_is_identical(tmp_path: Path) -> None:
    run = subprocess.run(
        [sys.executable, "tools/fingerprint.py", "--trials", "2", "--against", str(ROOT)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert run.returncode == 0, run.stdout + run.stderr[-2000:]
    lines = run.stdout.strip().splitlines()
    assert lines[-1] == "10 of 10 identical", run.stdout
    assert all(line.endswith("  same") for line in lines[:-1]), run.stdout
    wrong = subprocess.run(
        [sys.executable, "tools/fingerprint.py", "--against", str(tmp_path)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert wrong.returncode == 2 and "no piezofin_ros there" in wrong.stderr
    assert "Traceback" not in wrong.stderr
