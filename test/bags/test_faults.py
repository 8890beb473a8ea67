"""Bad files: truncated, corrupted, empty, non-MCAP bags, and bags without the expected topics.

Every reader of the suite must return what is readable, or stop with one clear error naming the
file; never crash, never hang.  ``benchmarks/bench_faults.py`` runs the same fuzz at a larger scale.
"""

from __future__ import annotations

import collections
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from mcap.records import Chunk, Message
from mcap.stream_reader import StreamReader, breakup_chunk
from rosbags.highlevel import AnyReader

from piezofin_ros.bags import BagError, read_messages, recover

from ..fuzz import KINDS, base_bag, run

BIN = Path(sys.executable).parent


def piezofin(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([BIN / "piezofin", *args], capture_output=True, text=True, timeout=120)


@pytest.fixture(scope="session")  # once per test worker: under xdist a worker interleaves modules
def base(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return base_bag(tmp_path_factory.mktemp("base") / "base.mcap")


def chunk_spans(path: Path) -> list[tuple[int, int, int]]:
    """``(start, end, messages inside)`` of each chunk record, read independently of the suite's reader."""
    out = []
    with open(path, "rb") as f:
        reader = StreamReader(f, emit_chunks=True)
        records = iter(reader.records)
        while True:
            start = reader._stream.count
            record = next(records, None)
            if record is None:
                break
            if isinstance(record, Chunk):
                n = sum(isinstance(r, Message) for r in breakup_chunk(record))
                out.append((start, reader._stream.count, n))
    return out


def chunk_ends(path: Path) -> list[tuple[int, int]]:
    return [(end, n) for _, end, n in chunk_spans(path)]


def test_a_cut_bag_keeps_every_complete_chunk(base: Path, tmp_path: Path) -> None:
    """A bag cut anywhere (a writer killed, a copy interrupted) gives every message of every chunk
    that ends before the cut, and reports where the damage is."""
    data = base.read_bytes()
    ends = chunk_ends(base)
    assert len(ends) > 20
    all_messages = list(read_messages(base))
    rng = np.random.default_rng(3)
    for cut in sorted(rng.integers(ends[0][0] + 1, len(data) - 1, size=40)):
        path = tmp_path / f"cut_{cut}.mcap"
        path.write_bytes(data[:cut])
        damages: list = []
        got = list(read_messages(path, on_damage=damages.append))
        expected = sum(n for end, n in ends if end <= cut)
        assert len(got) == expected, cut
        assert got == all_messages[: len(got)]
        if cut < ends[-1][0]:
            assert damages and damages[-1].fatal and str(path) in str(damages[-1])


@pytest.mark.parametrize("kind", ["delete", "duplicate", "garbage"])
def test_reading_resumes_at_the_next_intact_chunk(base: Path, tmp_path: Path, kind: str) -> None:
    """A deleted, duplicated or garbled byte range costs the chunks it touches and nothing more:
    reading resumes at the next chunk that passes its CRC, and a duplicated chunk is read once."""
    data = base.read_bytes()
    spans = chunk_spans(base)
    everything = list(read_messages(base))
    firsts = np.cumsum([0] + [n for _, _, n in spans])
    rng = np.random.default_rng(11)
    for trial in range(12):
        k = int(rng.integers(1, len(spans) - 2))  # damage inside chunk k, away from the first and last
        start, end, _ = spans[k]
        i = int(rng.integers(start + 1, end - 200))
        j = i + int(rng.integers(1, 200))
        if kind == "delete":
            damaged = data[:i] + data[j:]
        elif kind == "duplicate":
            damaged = data[:j] + data[i:j] + data[j:]
        else:
            damaged = data[:i] + rng.integers(0, 256, size=j - i, dtype=np.uint8).tobytes() + data[j:]
        path = tmp_path / f"{kind}_{trial}.mcap"
        path.write_bytes(damaged)
        notes: list = []
        got = list(read_messages(path, on_damage=notes.append))
        lost = everything[firsts[k] : firsts[k + 1]]
        expected = everything[: firsts[k]] + everything[firsts[k + 1] :]
        if kind == "duplicate" and got == everything:
            continue  # the copy landed where it spoils nothing the CRC checks
        assert got == expected, (trial, i, j, len(got), len(expected))
        assert notes and not any(n.fatal for n in notes) and len(lost) > 0


def test_a_bag_with_a_broken_start_keeps_its_chunks(base: Path, tmp_path: Path) -> None:
    """Magic and header overwritten: still an MCAP file, as its chunks pass their CRCs; random bytes
    of the same size are refused, naming the file."""
    data = base.read_bytes()
    spans = chunk_spans(base)
    everything = list(read_messages(base))
    broken = tmp_path / "broken_start.mcap"
    broken.write_bytes(bytes(40) + data[40:])
    assert spans[0][0] > 40
    notes: list = []
    assert list(read_messages(broken, on_damage=notes.append)) == everything
    assert "no MCAP magic" in notes[0].reason and not notes[0].fatal
    noise = tmp_path / "noise.mcap"
    noise.write_bytes(np.random.default_rng(5).integers(0, 256, size=len(data), dtype=np.uint8).tobytes())
    with pytest.raises(BagError, match=r"noise\.mcap: not a readable MCAP file"):
        list(read_messages(noise))


HEAVY = ["estimate", "diagnose_scan", "diagnose"]
FUZZ_FILES, FUZZ_SHARDS = 1000, 4


def test_a_fixed_sample_of_fuzzed_bags_never_crash_or_hang(tmp_path: Path) -> None:
    """The fast tier's fuzz: 20 mutated bags, every kind of damage twice, each read in full and given
    to a heavy reader in turn (the estimator's replay, the diagnosis's scan, its data path)."""
    outcomes = run(tmp_path, 20, seed=7, which_per_file=lambda k: ["read", HEAVY[k % 3]], kinds=KINDS)
    failures = [o for o in outcomes if o.result.startswith("FAIL")]
    assert not failures, failures[:10]
    assert collections.Counter(o.kind for o in outcomes if o.reader == "read") == dict.fromkeys(KINDS, 2)
    results = collections.Counter(o.result for o in outcomes if o.reader == "read")
    assert results["ok"] >= 6 and results["error"] >= 2  # both: readable parts kept, clear refusals
    assert max(o.seconds for o in outcomes) < 10.0


@pytest.mark.long  # bash tools/test.sh --long, and CI; the fixed sample above is in every tier
@pytest.mark.slow
@pytest.mark.parametrize("shard", range(FUZZ_SHARDS))
def test_fuzzed_bags_never_crash_or_hang(tmp_path: Path, shard: int) -> None:
    """1000 mutated bags (random kinds of damage), in four shards of 250 that run in parallel; each
    read in full, then given to one of the estimator's replay, the diagnosis's scan or the whole
    diagnosis data path (in turn)."""
    size = FUZZ_FILES // FUZZ_SHARDS
    mine = range(shard * size, (shard + 1) * size)
    outcomes = run(
        tmp_path, FUZZ_FILES, seed=20261122, which_per_file=lambda k: ["read", HEAVY[k % 3]], only=mine
    )
    failures = [o for o in outcomes if o.result.startswith("FAIL")]
    assert not failures, failures[:10]
    kinds = collections.Counter(o.kind for o in outcomes if o.reader == "read")
    assert set(kinds) == set(KINDS) and sum(kinds.values()) == size
    results = collections.Counter(o.result for o in outcomes if o.reader == "read")
    # both, in each quarter: readable parts kept, clear refusals (the whole run asked > 300 and > 50)
    assert results["ok"] > 75 and results["error"] > 12
    assert max(o.seconds for o in outcomes) < 10.0


@pytest.mark.fast_cases("-empty")
@pytest.mark.parametrize(
    ("content", "why"),
    [
        (None, "no such file"),
        (b"", "empty"),
        (b"PK\x03\x04 a zip, not a bag", "no MCAP magic"),
        (b"\x89MCAP0\r\n\x01\xff\xff\xff\xff\xff\xff\xff\x7f", "not a readable MCAP"),
    ],
)
def test_unreadable_files_name_the_file_and_the_problem(
    tmp_path: Path, content: bytes | None, why: str
) -> None:
    path = tmp_path / "bad.mcap"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(BagError, match=why) as info:
        list(read_messages(path))
    assert str(path) in str(info.value)
    for cmd in (["estimate", str(path)], ["diagnose", str(path)], ["bag", "recover", str(path)]):
        run_ = piezofin(*cmd)
        assert run_.returncode == 2, (cmd, run_.stderr)
        assert str(path) in run_.stderr and "Traceback" not in run_.stderr


def test_recover_a_cut_bag_into_a_complete_one(base: Path, tmp_path: Path) -> None:
    data = base.read_bytes()
    cut = tmp_path / "killed.mcap"
    cut.write_bytes(data[: int(len(data) * 0.7)])
    run_ = piezofin("bag", "recover", str(cut))
    assert run_.returncode == 0, run_.stderr
    out = tmp_path / "killed.recovered.mcap"
    assert "damaged at byte" in run_.stdout and str(out) in run_.stdout
    kept = list(read_messages(cut))
    with AnyReader([out]) as reader:  # an independent reader: complete, indexed, every message
        assert reader.message_count == len(kept) > 0
        topics = {c.topic for c in reader.connections}
    assert "/fin/drive" in topics
    assert list(read_messages(out)) == kept
    again = piezofin("bag", "recover", str(cut))
    assert again.returncode == 2 and "never overwrites" in again.stderr
    report = recover(base, tmp_path / "whole.mcap")
    assert report.complete and report.messages == len(list(read_messages(base)))


def test_bags_without_the_expected_topics_say_so(tmp_path: Path, base: Path) -> None:
    from piezofin_ros.bags import BagWriter
    from piezofin_ros.diagnosis.data import DataError, from_bags
    from piezofin_ros.estimation.offline import replay_estimates
    from piezofin_ros.physics.fin import load_fin

    only_clock = tmp_path / "clock_only.mcap"
    with BagWriter(only_clock) as bag:
        for m in read_messages(base, topics=["/clock"]):
            bag.add_topic(m.topic, m.type_name)
            bag.write(m.topic, m.log_time_ns, m.data)
    fin = load_fin("M8528-P1")
    with pytest.raises(BagError, match=r"clock_only\.mcap: no message on /fin/drive"):
        replay_estimates(only_clock, fin)
    with pytest.raises((BagError, DataError), match=r"clock_only\.mcap"):
        from_bags([only_clock], fin)
    with pytest.raises(BagError, match="namespace"):
        replay_estimates(base, fin, namespace="/other_fin")
