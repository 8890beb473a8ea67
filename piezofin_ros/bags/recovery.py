"""Recovering a bag whose writer was killed: every intact message copied into a complete, indexed
file (:func:`recover`), with the QoS the channels were recorded with."""

from __future__ import annotations

import itertools
import os
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from ..errors import BagError
from .reader import MCAP_MAGIC, BagMessage, Damage, read_messages
from .writer import BagWriter


@dataclass(frozen=True)
class Recovery:
    """What :func:`recover` saved."""

    source: Path
    output: Path
    messages: int
    counts: dict[str, int]
    first_ns: int | None
    last_ns: int | None
    bytes_read: int  # up to the first fatal damage (the whole file if none)
    size: int
    damages: tuple[Damage, ...]

    @property
    def complete(self) -> bool:
        return not self.damages

    def summary(self) -> str:
        span = (
            f", log time {self.first_ns * 1e-9:.3f} .. {self.last_ns * 1e-9:.3f} s"
            if self.first_ns is not None and self.last_ns is not None
            else ""
        )
        lines = [
            f"{self.output}: {self.messages} messages on {len(self.counts)} topics{span}",
            f"read {self.bytes_read} of {self.size} bytes of {self.source} "
            f"({100.0 * self.bytes_read / max(self.size, 1):.1f} %)",
        ]
        lines += [f"  {t}: {c}" for t, c in sorted(self.counts.items())]
        lines += [f"damage: {d}" for d in self.damages] or ["no damage: the source was complete"]
        return "\n".join(lines)


def recover(source: str | os.PathLike[str], output: str | os.PathLike[str] | None = None) -> Recovery:
    """Copy every readable message of ``source`` (e.g. a bag whose recorder was killed) into a
    complete, indexed MCAP at ``output`` (default ``<source>.recovered.mcap``, never overwritten).

    Raises :class:`BagError` when nothing can be read or the output exists.
    """
    src = Path(source)
    out = Path(output) if output is not None else src.with_name(src.stem + ".recovered.mcap")
    if out.exists():
        raise BagError(f"{out}: exists; recover never overwrites a file")
    damages: list[Damage] = []
    size = src.stat().st_size if src.is_file() else 0
    messages = read_messages(src, on_damage=damages.append)
    try:
        first = next(messages, None)  # BagError here: nothing to recover, no output written
    except BagError:
        end = _header_end(src)
        if end is None or not damages or any(d.offset < end for d in damages):
            raise
        first = None  # an MCAP header, then the cut of a writer killed before its first chunk: empty
    # written under a temporary name, moved to ``out`` only when complete (never a partial file)
    tmp = out.with_name(f".{out.name}.{os.getpid()}.partial")
    try:
        counts, first_ns, last_ns = _copy_messages(
            itertools.chain([first] if first else [], messages), tmp, out.name
        )
        os.link(tmp, out)  # fails if ``out`` appeared meanwhile: still never overwritten
    except FileExistsError:
        raise BagError(f"{out}: exists; recover never overwrites a file") from None
    except OSError as exc:
        raise BagError(f"{out}: cannot write the recovered bag ({exc.strerror or exc})") from None
    finally:
        tmp.unlink(missing_ok=True)
    fatal = [d for d in damages if d.fatal]
    return Recovery(
        src,
        out,
        sum(counts.values()),
        counts,
        first_ns,
        last_ns,
        fatal[0].offset if fatal else size,
        size,
        tuple(damages),
    )


def _header_end(path: Path) -> int | None:
    """Where the MCAP magic and a whole header record end, or None if the file does not start so."""
    try:
        with open(path, "rb") as fh:
            start = fh.read(len(MCAP_MAGIC) + 9)
            size = os.fstat(fh.fileno()).st_size
    except OSError:
        return None
    if len(start) < len(MCAP_MAGIC) + 9 or not start.startswith(MCAP_MAGIC + b"\x01"):
        return None
    end = len(start) + int.from_bytes(start[len(MCAP_MAGIC) + 1 :], "little")
    return end if end <= size else None


def _copy_messages(
    messages: Iterable[BagMessage], path: Path, name: str
) -> tuple[dict[str, int], int | None, int | None]:
    """Write ``messages`` to a new, complete bag at ``path`` (their channels' QoS kept, rosbag2's
    metadata record rebuilt); returns counts and the log-time span."""
    first_ns = last_ns = None
    bag = BagWriter(path, metadata={"recovered_by": "piezofin bag recover"}, file_name=name)
    try:
        for m in messages:
            if not bag.has_topic(m.topic):
                bag.add_topic(m.topic, m.type_name, m.offered_qos, strict=False)
            bag.write(m.topic, m.log_time_ns, m.data)
            first_ns = m.log_time_ns if first_ns is None else min(first_ns, m.log_time_ns)
            last_ns = m.log_time_ns if last_ns is None else max(last_ns, m.log_time_ns)
    except BaseException:
        bag.abandon()
        path.unlink(missing_ok=True)
        raise
    bag.close()
    return dict(bag.counts), first_ns, last_ns
