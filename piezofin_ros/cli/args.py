"""What every command of the CLI shares: its exit statuses, its one-line error, and the checks of
its arguments (frequencies, outputs that can be written), imported by :mod:`.main` and by each
command's module (never the other way round).
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..control.trials import parse_frequencies as frequencies_of
from ..errors import CliError, ControlError

EXIT_USAGE = 2
#: The work ran, but its result is not to be trusted (said on standard error, with the cause).
EXIT_UNTRUSTED = 3


class UsageError(CliError):
    """A user-facing error: printed as one line, exit status 2."""


def add_fins(parser: argparse.ArgumentParser) -> None:
    """``--fins``: fin presets or YAML files, the paper's three by default (the commands that compare
    fins: ``swim``, ``watts``)."""
    from ..diagnosis.paper import PAPER_FINS

    parser.add_argument(
        "--fins", nargs="+", default=list(PAPER_FINS), help="fin presets or YAML (default: the paper's)"
    )


def parse_frequencies(spec: Sequence[str], option: str = "--freq") -> np.ndarray:
    """:func:`~piezofin_ros.control.trials.parse_frequencies`, a mistake one line naming ``option``."""
    try:
        return frequencies_of(spec, option)
    except ControlError as exc:
        raise UsageError(str(exc)) from None


def writable_path(option: str, path: str | Path) -> None:
    """``path`` can be written: its folder exists (made if need be) and takes files, and it is no
    folder itself; else one line naming ``option``."""
    path = Path(path)
    if path.is_dir():
        raise UsageError(f"{option} {path}: a folder, not a file")
    writable_folder(option, path.parent, f"{option} {path}: its folder")


def writable_folder(option: str, folder: Path, what: str = "") -> None:
    """``folder`` exists (made if need be) and takes files; else one line naming ``option``."""
    what = what or option
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"{what} {folder}: cannot make it ({exc.strerror or exc})") from None
    if not os.access(folder, os.W_OK):
        raise UsageError(f"{what} {folder}: not writable")
