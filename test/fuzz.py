"""Mutated bags for the fault tests and ``benchmarks/bench_faults.py``: damage a good MCAP the ways
disks, copies and killed writers do, then run each reader of the suite on it.

A reader passes a file when it returns, or raises its documented error (:class:`BagError`,
:class:`DataError`) with the file's path in the text, within the time limit.  Anything else (another
exception, a hang) is a failure, reported with the mutation that caused it.
"""

from __future__ import annotations

import signal
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from piezofin_ros.bags import BagError, BagWriter, read_messages
from piezofin_ros.diagnosis.data import DataError, from_bags, scan_bag
from piezofin_ros.estimation.offline import replay_estimates
from piezofin_ros.physics.fin import load_fin

SAMPLE = Path(__file__).resolve().parents[1] / "bags" / "sample_M8528-P1.mcap"
KINDS = ("truncate", "flip", "zero", "garbage", "delete", "duplicate", "swap", "append", "header", "random")


def base_bag(path: Path, seconds: float = 14.0, chunk_kib: int = 32) -> Path:
    """The sample bag's first ``seconds`` (drive off, then a burst) in small chunks: many chunks to hit."""
    messages = list(read_messages(SAMPLE))
    t0 = messages[0].log_time_ns
    with BagWriter(path, chunk_size=chunk_kib * 1024) as bag:
        for m in messages:
            if m.log_time_ns - t0 > seconds * 1e9:
                break
            bag.add_topic(m.topic, m.type_name)
            bag.write(m.topic, m.log_time_ns, m.data)
    return path


def mutate(data: bytes, rng: np.random.Generator, kind: str | None = None) -> tuple[str, bytes]:
    """One damaged copy of ``data`` (an MCAP file) and the kind of damage."""
    kind = kind or str(rng.choice(KINDS))
    n = len(data)
    b = bytearray(data)

    def span() -> tuple[int, int]:
        i = int(rng.integers(0, n))
        return i, min(n, i + int(rng.integers(1, 4096)))

    if kind == "truncate":
        return kind, data[: int(rng.integers(0, n))]
    if kind == "flip":
        for i in rng.integers(0, n, size=int(rng.integers(1, 40))):
            b[int(i)] ^= 1 << int(rng.integers(0, 8))
    elif kind == "zero":
        i, j = span()
        b[i:j] = bytes(j - i)
    elif kind == "garbage":
        i, j = span()
        b[i:j] = rng.integers(0, 256, size=j - i, dtype=np.uint8).tobytes()
    elif kind == "delete":
        i, j = span()
        del b[i:j]
    elif kind == "duplicate":
        i, j = span()
        b[j:j] = b[i:j]
    elif kind == "swap":
        i, j = span()
        k = int(rng.integers(0, n - (j - i)))
        b[i:j], b[k : k + j - i] = b[k : k + j - i], b[i:j]
    elif kind == "append":
        b += rng.integers(0, 256, size=int(rng.integers(1, 2000)), dtype=np.uint8).tobytes()
    elif kind == "header":
        size = int(rng.integers(1, 64))
        b[:size] = rng.integers(0, 256, size=size, dtype=np.uint8).tobytes()
    elif kind == "random":
        return kind, rng.integers(0, 256, size=int(rng.integers(0, 5000)), dtype=np.uint8).tobytes()
    else:
        raise ValueError(f"unknown mutation {kind!r}")
    return kind, bytes(b)


class Hang(Exception):
    pass


def _alarm(signum: int, frame: object) -> None:
    raise Hang


FIN = None


def readers() -> dict[str, Callable[[Path], Any]]:
    """Each way the suite reads a bag (the player's reading is ``read_messages`` itself)."""
    global FIN
    FIN = FIN or load_fin("M8528-P1")
    return {
        "read": lambda p: sum(1 for _ in read_messages(p, on_damage=None)),
        "estimate": lambda p: replay_estimates(p, FIN),
        "diagnose_scan": lambda p: scan_bag(p, "/fin"),
        "diagnose": lambda p: from_bags([p], FIN),
    }


@dataclass(frozen=True)
class Outcome:
    reader: str
    kind: str
    result: str  # "ok", "error" (clear, named), "FAIL: ..."
    seconds: float


def check(path: Path, kind: str, which: list[str], time_limit_s: float = 20.0) -> list[Outcome]:
    """Run the named readers on ``path``; each must return or raise its clear error in time."""
    out = []
    previous = signal.signal(signal.SIGALRM, _alarm)
    try:
        for name in which:
            fn = readers()[name]
            t0 = time.perf_counter()
            signal.setitimer(signal.ITIMER_REAL, time_limit_s)
            try:
                fn(path)
                result = "ok"
            except (BagError, DataError) as exc:
                result = "error" if str(path) in str(exc) else f"FAIL: error without the file name: {exc}"
            except Hang:
                result = f"FAIL: no answer within {time_limit_s} s"
            except Exception as exc:  # the point of the test: anything else is a crash
                result = f"FAIL: {type(exc).__name__}: {exc}"
            finally:
                signal.setitimer(signal.ITIMER_REAL, 0)
            out.append(Outcome(name, kind, result, time.perf_counter() - t0))
    finally:
        signal.signal(signal.SIGALRM, previous)
    return out


def run(
    directory: Path,
    n: int,
    seed: int,
    which_per_file: Callable[[int], list[str]],
    only: range | None = None,
    kinds: tuple[str, ...] | None = None,
) -> list[Outcome]:
    """``n`` mutated copies of the base bag in ``directory``, each checked by the chosen readers.

    ``only``: check just these of the ``n`` (a shard; the others are drawn but not checked, so a
    shard's files are the same as in the whole run); ``kinds``: the k-th file's damage is
    ``kinds[k % len(kinds)]`` (a fixed sample of every kind) instead of a random kind."""
    base = base_bag(directory / "base.mcap")
    data = base.read_bytes()
    rng = np.random.default_rng(seed)
    outcomes: list[Outcome] = []
    for k in range(n):
        kind, mutated = mutate(data, rng, kinds[k % len(kinds)] if kinds else None)
        if only is not None and k not in only:
            continue
        path = directory / f"mutant_{seed}_{k:05d}_{kind}.mcap"
        path.write_bytes(mutated)
        outcomes += check(path, kind, which_per_file(k))
        path.unlink()
    return outcomes
