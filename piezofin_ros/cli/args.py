"""What every command of the CLI shares: its exit statuses, its one-line error, and the checks of
its arguments (frequencies, outputs that can be written), imported by :mod:`.main` and by each
command's module (never the other way round).
"""

from __future__ import annotations

import argparse
import os
import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..control.trials import parse_frequencies as frequencies_of
from ..errors import CliError, ControlError
from ..files import written_by_us

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


#: What ``--plot`` writes (matplotlib's format follows the suffix; with none it added ``.png`` to
#: the name, so ``--plot DIR`` wrote ``DIR.png`` and said "wrote DIR").
PLOT_SUFFIXES = (".png", ".pdf", ".svg")


def writable_path(option: str, path: str | Path, suffixes: Sequence[str] = ()) -> None:
    """``path`` can be written, checked before the work that makes it: a usable name (no NUL byte;
    one of ``suffixes`` when given), nothing there yet but a figure the suite wrote itself (an output
    never replaces a user's file: choose another name; ``piezofin watts --plot out/watts.png`` twice
    replaces its own), its folder made if need be, and a file can be created in it (tried:
    ``/proc/x.png`` passed a permission check as root, then failed after the work); else one line
    naming ``option``."""
    text = os.fspath(path)
    if "\0" in text:
        raise UsageError(f"{option} {text!r}: not a usable file name (a NUL byte)")
    path = Path(text)
    if suffixes and path.suffix.lower() not in suffixes:
        raise UsageError(f"{option} {path}: give a file name ending in {', '.join(suffixes)}")
    if path.is_dir():
        raise UsageError(f"{option} {path}: a folder, not a file")
    if path.exists() or path.is_symlink():
        if suffixes and not path.is_symlink() and written_by_us(path):
            if not os.access(path, os.W_OK):
                raise UsageError(f"{option} {path}: exists and is not writable")
            return  # the suite's own figure, from an earlier run: replaced
        raise UsageError(
            f"{option} {path}: exists and is not a figure this suite wrote; choose another name (a "
            "user's file is never overwritten)"
        )
    writable_folder(option, path.parent, f"{option} {path}: its folder")
    try:  # the one sure test: create it (exclusively), then leave the name free for the work
        os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644))
    except OSError as exc:
        raise UsageError(f"{option} {path}: cannot be written ({exc.strerror or exc})") from None
    os.unlink(path)


def writable_folder(option: str, folder: Path, what: str = "") -> None:
    """``folder`` exists (made if need be) and takes files; else one line naming ``option``."""
    what = what or option
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(
            f"{what} {folder}: cannot write there (cannot make the folder: {exc.strerror or exc})"
        ) from None
    if not os.access(folder, os.W_OK):
        raise UsageError(f"{what} {folder}: not writable")
    try:  # (root passes os.access anywhere: a file made and removed is the sure test)
        fd, probe = tempfile.mkstemp(prefix=".piezofin-probe-", dir=folder)
    except OSError as exc:
        raise UsageError(f"{what} {folder}: cannot write in it ({exc.strerror or exc})") from None
    os.close(fd)
    os.unlink(probe)
