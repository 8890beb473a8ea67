"""Files the suite is handed: regular files only, checked before any work; outputs that keep the
user's files.

Every configuration file, bag and CSV the suite reads is opened here.  The open itself cannot
block: it is made with ``O_NONBLOCK`` (a FIFO with no writer opens at once instead of waiting for
ever, with SIGINT and SIGTERM held off in the C call), then the open file is checked with ``fstat``,
so what is read is what was checked (no window in which the path could be swapped).  A FIFO, a
device, a socket or a directory is refused with one line naming the path; so is a path with a NUL
byte, which the operating system cannot take.

Outputs: :func:`refuse_existing` says, before a command starts its work, that an output would
replace a file the user owns.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import Any, BinaryIO

from .errors import PiezofinError


class InputFileError(PiezofinError, ValueError):
    """A path the suite cannot read as a file (the message names it and says why)."""


class OutputFileError(PiezofinError, ValueError):
    """An output path the suite will not write (it exists, or cannot be a file)."""


def _kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a directory"
    if stat.S_ISFIFO(mode):
        return "a FIFO"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def open_regular(
    path: str | os.PathLike[str], error: type[Exception] = InputFileError, what: str = ""
) -> BinaryIO:
    """``path`` opened for reading in binary, or ``error`` naming it: missing, unreadable, not a
    regular file (FIFO, device, socket, directory), or a name the system cannot take (a NUL byte).
    Never blocks."""
    label = f"{what} {path}" if what else str(path)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC)
    except FileNotFoundError:
        raise error(f"{label}: cannot read (no such file)") from None
    except IsADirectoryError:
        raise error(f"{label}: cannot read (a directory, not a file)") from None
    except OSError as exc:
        raise error(f"{label}: cannot open ({exc.strerror or exc})") from None
    except (ValueError, TypeError) as exc:  # a NUL byte in the name, a name that is no path
        raise error(f"{label!r}: not a usable file name ({exc})") from None
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise error(
                f"{label}: cannot read ({_kind(mode)}, not a regular file; refused before reading it)"
            )
        os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def check_regular(
    path: str | os.PathLike[str], error: type[Exception] = InputFileError, what: str = ""
) -> Path:
    """``path`` when it is a regular file the suite can open (see :func:`open_regular`), else
    ``error``: for readers that take a path and open it later."""
    with open_regular(path, error, what):
        pass
    return Path(path)


def output_path(path: str | os.PathLike[str], what: str, *, force: bool = False) -> Path:
    """An output file ``path``, checked before the work that makes it: refused when it exists (unless
    ``force``) or cannot be a file (a directory, a FIFO, a device, a NUL byte, a parent that is not a
    directory); ``OutputFileError`` naming ``what`` (the option) and the path."""
    text = os.fspath(path)
    if "\0" in str(text):
        raise OutputFileError(f"{what} {text!r}: not a usable file name (a NUL byte)")
    p = Path(text)
    try:
        st = os.stat(p)
    except FileNotFoundError:
        st = None
    except OSError as exc:
        raise OutputFileError(f"{what} {p}: cannot be written ({exc.strerror or exc})") from None
    if st is not None:
        if not stat.S_ISREG(st.st_mode):
            raise OutputFileError(f"{what} {p}: {_kind(st.st_mode)}, not a file to write")
        if not force:
            raise OutputFileError(f"{what} {p}: exists (give --force to replace it)")
    parent = p.parent if str(p.parent) else Path(".")
    if parent.exists() and not parent.is_dir():
        raise OutputFileError(f"{what} {p}: {parent} is not a directory")
    probe = parent
    while not probe.exists():  # the nearest existing ancestor: it will hold the new directories
        probe = probe.parent
    if not os.access(probe, os.W_OK | os.X_OK):
        raise OutputFileError(f"{what} {p}: {probe} is not writable")
    return p


#: The name the suite writes into every figure it makes (a PNG's ``Software`` text, a PDF's or an
#: SVG's ``Creator``), so that an output it wrote itself can be replaced and a user's file never is.
SOFTWARE = "piezofin_ros"
_MARKS = {
    ".png": b"Software\x00" + SOFTWARE.encode(),
    ".pdf": b"/Creator (" + SOFTWARE.encode(),
    ".svg": b"<dc:title>" + SOFTWARE.encode(),
}
_MARK_SCAN_BYTES = 32 * 1024 * 1024


def figure_metadata(path: str | os.PathLike[str]) -> dict[str, str]:
    """matplotlib's ``savefig(metadata=...)`` that marks a figure as the suite's."""
    suffix = Path(path).suffix.lower()
    return {"Software": SOFTWARE} if suffix == ".png" else {"Creator": SOFTWARE}


def save_figure(fig: Any, path: str | os.PathLike[str], dpi: int = 110, what: str = "--plot") -> None:
    """A matplotlib figure written to ``path`` (its folders made, marked as the suite's: its
    :func:`figure_metadata`) and closed whatever happens; a path it cannot write is one
    :class:`OutputFileError` naming ``what`` and the path."""
    import matplotlib.pyplot as plt

    try:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=dpi, metadata=figure_metadata(path))
    except OSError as exc:
        raise OutputFileError(f"{what} {path}: cannot write ({exc.strerror or exc})") from None
    finally:
        plt.close(fig)


def written_by_us(path: str | os.PathLike[str]) -> bool:
    """``path`` is a figure the suite wrote (its mark, :data:`SOFTWARE`, where matplotlib puts it)."""
    mark = _MARKS.get(Path(path).suffix.lower())
    if mark is None:
        return False
    try:
        with open_regular(path) as fh:
            return mark in fh.read(_MARK_SCAN_BYTES)
    except InputFileError:
        return False
