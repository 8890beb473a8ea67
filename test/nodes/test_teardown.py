"""A node whose ROS teardown hangs still exits, with its status and where it waited (the two-fin
launch once saw ``fin_sims`` killed with -9 after closing both fins on a loaded machine)."""

from __future__ import annotations

import subprocess
import sys
import time

SNIPPET = """
import time
from piezofin_ros.nodes._common import TeardownWatchdog
TeardownWatchdog.TEARDOWN_S = 0.5
watchdog = TeardownWatchdog(3).start()
{then}
"""


def run(then: str) -> tuple[subprocess.CompletedProcess[str], float]:
    t0 = time.monotonic()
    out = subprocess.run(
        [sys.executable, "-c", SNIPPET.format(then=then)], capture_output=True, text=True, timeout=60
    )
    return out, time.monotonic() - t0


def test_a_hung_teardown_ends_with_the_status_and_the_stacks() -> None:
    out, took = run("time.sleep(30)  # (a teardown that never returns)")
    assert out.returncode == 3 and took < 20, (out.returncode, took)
    assert "tearing down the ROS entities took over 0.5 s" in out.stderr
    assert 'File "<string>", line 6' in out.stderr  # the stack of the thread that waited


def test_a_teardown_in_time_is_left_alone() -> None:
    out, _ = run("watchdog.cancel()\ntime.sleep(1.0)\nprint('exited normally')")
    assert out.returncode == 0 and out.stdout.strip() == "exited normally" and not out.stderr
