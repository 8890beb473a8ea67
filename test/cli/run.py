"""``piezofin COMMAND ...`` as a user runs it: its own process, no standard input, the project's
environment only (what the CLI tests of one command share)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

BIN = Path(sys.executable).parent


def piezofin(command: str, *args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(BIN / "piezofin"), command, *args],
        capture_output=True,
        text=True,
        timeout=120,
        stdin=subprocess.DEVNULL,
        cwd=cwd,
        env={"MPLBACKEND": "Agg", "PATH": str(BIN)},
    )
