"""``piezofin COMMAND ...`` as a user runs it: its own process, no standard input, the project's
environment only (what the CLI tests of one command share)."""

from __future__ import annotations

import os
import shlex
import shutil
import signal
import subprocess
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path

BIN = Path(sys.executable).parent


def run_showing_where(
    cmd: Sequence[str], *, timeout: float, env: Mapping[str, str] | None = None, cwd: Path | None = None
) -> subprocess.CompletedProcess[str]:
    """``subprocess.run(cmd, capture_output=True, text=True, stdin=DEVNULL)``, but a command still
    running after ``timeout`` is first asked where its Python is (faulthandler's stacks on SIGABRT),
    then killed, and the test fails with those stacks: a hang seen once on a loaded CI is then a
    place in the code, not a guess (2026-12-07: a campaign's analysis, 5 s alone, outlived 180 s)."""
    env = {**(os.environ if env is None else env), "PYTHONFAULTHANDLER": "1"}
    with subprocess.Popen(
        list(cmd),
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=cwd,
    ) as proc:
        try:
            out, err = proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGABRT)
            try:
                out, err = proc.communicate(timeout=15)
            except subprocess.TimeoutExpired:
                proc.kill()
                out, err = proc.communicate()
            raise AssertionError(
                f"`{shlex.join(cmd)}` still ran after {timeout:g} s; where its Python was "
                f"(faulthandler, on SIGABRT):\n{err[-8000:]}\nits output's end:\n{out[-2000:]}"
            ) from None
    return subprocess.CompletedProcess(list(cmd), proc.returncode, out, err)


def console(
    exe: str, *args: str, timeout: float = 120, env: Mapping[str, str] | None = None, cwd: Path | None = None
) -> subprocess.CompletedProcess[str]:
    """A console script of this environment (``exe``, found beside this Python, else on the PATH) as
    :func:`run_showing_where` runs it."""
    path = shutil.which(exe, path=str(BIN)) or shutil.which(exe)
    assert path, f"console script {exe!r} is not installed"
    return run_showing_where([path, *args], timeout=timeout, env=env, cwd=cwd)


def piezofin(command: str, *args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return run_showing_where(
        [str(BIN / "piezofin"), command, *args],
        timeout=120,
        cwd=cwd,
        env={"MPLBACKEND": "Agg", "PATH": str(BIN)},
    )
