"""Hostile files: decompression bombs for every bag reader, YAML bombs for every configuration reader.

Each reader runs as a user runs it (the console scripts, in their own process), and is measured:
peak resident memory at most 100x the file's size + 200 MB, or one error line naming the file
with no traceback, within 30 s.  The files are built here, for a class of attack each.
"""

from __future__ import annotations

import io
import json
import os
import signal
import struct
import subprocess
import time
import zlib
from pathlib import Path

import lz4.frame
import pytest
import zstandard

from piezofin_ros.bags import MCAP_MAGIC, message_definition

from ..rosutil import BIN, clean_env

TOPIC = "/fin/drive"
TYPE = "std_msgs/msg/Float64MultiArray"


# ------------------------------------------------------------------------------ MCAP by hand
def _record(opcode: int, body: bytes) -> bytes:
    return bytes([opcode]) + struct.pack("<Q", len(body)) + body


def _string(s: str | bytes) -> bytes:
    b = s.encode() if isinstance(s, str) else s
    return struct.pack("<I", len(b)) + b


def _header() -> bytes:
    return MCAP_MAGIC + _record(0x01, _string("ros2") + _string("attacker"))


def _schema_channel() -> bytes:
    schema = _record(
        0x03, struct.pack("<H", 1) + _string(TYPE) + _string("ros2msg") + _string(message_definition(TYPE))
    )
    channel = _record(0x04, struct.pack("<HH", 1, 1) + _string(TOPIC) + _string("cdr") + struct.pack("<I", 0))
    return schema + channel


def _message(t_ns: int, payload: bytes = b"") -> bytes:
    return _record(0x05, struct.pack("<HIQQ", 1, 0, t_ns, t_ns) + payload)


def _chunk(pieces: int, piece: bytes, compression: str, claim: int | None = None) -> bytes:
    """A chunk of ``pieces`` copies of ``piece`` (records), compressed by streaming: the test never
    holds the uncompressed bytes.  ``claim`` overrides the uncompressed size it states."""
    crc, size = 0, 0
    out = io.BytesIO()
    if compression == "zstd":
        comp = zstandard.ZstdCompressor(level=3).compressobj()
        for _ in range(pieces):
            out.write(comp.compress(piece))
            crc, size = zlib.crc32(piece, crc), size + len(piece)
        out.write(comp.flush())
    else:
        comp = lz4.frame.LZ4FrameCompressor()
        out.write(comp.begin())
        for _ in range(pieces):
            out.write(comp.compress(piece))
            crc, size = zlib.crc32(piece, crc), size + len(piece)
        out.write(comp.flush())
    data = out.getvalue()
    body = struct.pack("<QQQI", 0, 10**9, claim if claim is not None else size, crc)
    body += _string(compression) + struct.pack("<Q", len(data)) + data
    return _record(0x06, body)


def _footer() -> bytes:
    return _record(0x02, struct.pack("<QQI", 0, 0, 0)) + MCAP_MAGIC


def bomb(path: Path, kind: str) -> Path:
    """The attacks: one chunk expanding to 1 GiB of empty messages (the one found), one that lies
    about its size, many chunks each under the per-chunk limit (zstd and lz4), and an unchunked
    flood of empty messages."""
    records = _message(10**9) * 4096  # 4096 empty messages, 31 B each
    piece = len(records)  # ~124 KiB
    with open(path, "wb") as f:
        f.write(_header())
        if kind == "one 1 GiB chunk":
            f.write(_chunk(1, _schema_channel(), "zstd"))
            f.write(_chunk((1 << 30) // piece, records, "zstd"))
        elif kind == "chunk lying about its size":
            f.write(_chunk(1, _schema_channel(), "zstd"))
            f.write(_chunk((1 << 30) // piece, records, "zstd", claim=1 << 20))
        elif kind in ("many chunks, zstd", "many chunks, lz4"):
            f.write(_chunk(1, _schema_channel(), "zstd"))
            comp = kind.split(", ")[1]
            for k in range(40):  # each just under the 32 MiB floor of the per-chunk limit, each different
                f.write(_chunk((30 << 20) // piece, _message(10**9 + k) * 4096, comp))
        elif kind == "unchunked flood":
            f.write(_schema_channel())
            for _ in range(100):  # 410 k empty messages, 12.7 MB
                f.write(records)
        f.write(_footer())
    return path


KINDS = [
    "one 1 GiB chunk",
    "chunk lying about its size",
    "many chunks, zstd",
    "many chunks, lz4",
    "unchunked flood",
]
READERS = {
    "estimate": ["piezofin", "estimate", "{bag}"],
    "recover": ["piezofin", "bag", "recover", "{bag}", "-o", "{out}"],
    "diagnose": ["piezofin", "diagnose", "{bag}", "--quiet"],
}


#: Runs argv[1:] and prints its status and peak resident memory (its own children's largest, KiB):
#: a process of its own, so that no other child of the test process counts.
_MEASURE = (
    "import resource, subprocess, sys; "
    "r = subprocess.run(sys.argv[1:], stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL); "
    "print(r.returncode, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)"
)


def run_measured(argv: list[str], timeout: float = 60.0) -> tuple[int, str, float, float]:
    """Run a command in its own process; returns (status, stderr, wall s, peak RSS in MB)."""
    t0 = time.monotonic()
    proc = subprocess.Popen(
        [str(BIN / "python"), "-c", _MEASURE, *argv],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=clean_env(),
        text=True,
        start_new_session=True,
    )
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, err = proc.communicate()
        return -9, err, time.monotonic() - t0, float("nan")
    wall = time.monotonic() - t0
    status, peak_kib = (int(x) for x in out.split())
    return status, err, wall, peak_kib / 1024


@pytest.fixture(scope="session")  # once per test worker: under xdist a worker interleaves modules
def bombs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("bombs")
    return {k: bomb(d / f"{k.replace(' ', '_').replace(',', '')}.mcap", k) for k in KINDS}


@pytest.mark.slow
@pytest.mark.parametrize("reader", list(READERS))
@pytest.mark.parametrize("kind", KINDS)
def test_no_bag_takes_memory_it_does_not_hold(
    bombs: dict[str, Path], kind: str, reader: str, tmp_path: Path
) -> None:
    bag = bombs[kind]
    size_mb = bag.stat().st_size / 1e6
    argv = [a.format(bag=bag, out=tmp_path / "out.mcap") for a in READERS[reader]]
    argv[0] = str(BIN / argv[0])
    # each reader in a fresh child of a fresh helper, so ru_maxrss is that reader's own peak
    helper = [
        str(BIN / "python"),
        "-c",
        "import resource, subprocess, sys; r = subprocess.run(sys.argv[1:]); "
        "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, file=sys.stderr); "
        "sys.exit(r.returncode)",
        *argv,
    ]
    status, err, wall, _ = run_measured(helper)
    lines = err.strip().splitlines()
    peak_mb = int(lines[-1]) / 1024
    said = lines[:-1]
    print(f"{kind} / {reader}: {size_mb:.2f} MB file, status {status}, {wall:.1f} s, peak {peak_mb:.0f} MB")
    assert wall < 30.0
    assert peak_mb <= 100 * size_mb + 200, (peak_mb, said[-5:])
    assert not any("Traceback" in x for x in said), "\n".join(said[-20:])
    if status != 0:
        errors = [x for x in said if "error" in x.lower()]
        assert len(errors) == 1 and str(bag) in errors[0], said[-5:]
    if reader == "recover":
        assert status != 0 or (tmp_path / "out.mcap").exists()
        assert not list(tmp_path.glob(".*partial")), "a partial output was left behind"


# ------------------------------------------------------------------------------- YAML bombs
def yaml_bomb(path: Path, kind: str) -> Path:
    if kind == "20 MB":
        path.write_text("name: big\n" + "".join(f"k{i}: {i}.0\n" for i in range(1_500_000)))
    elif kind == "deep nesting":
        path.write_text("fin: " + "[" * 100_000 + "]" * 100_000 + "\n")
    elif kind == "100,000-digit integer":
        path.write_text("L: " + "9" * 100_000 + "\n")
    elif kind == "python tag":
        path.write_text("fin: !!python/object/apply:os.system ['true']\n")
    elif kind == "aliases":
        lines = ["a0: &a0 {x: 1.0}"] + [f"a{i}: &a{i} {{p: *a{i - 1}, q: *a{i - 1}}}" for i in range(1, 40)]
        path.write_text("\n".join(lines) + "\n")
    elif kind == "not UTF-8":
        path.write_bytes(b"name: \xff\xfe\n")
    return path


YAML_KINDS = ["20 MB", "deep nesting", "100,000-digit integer", "python tag", "aliases", "not UTF-8"]
YAML_READERS = {
    "fin (sweep --fin)": ["piezofin", "sweep", "--fin", "{f}", "--vpp", "400", "--freq", "5"],
    "model (sweep --model)": ["piezofin", "sweep", "--model", "{f}", "--vpp", "400", "--freq", "5"],
    "parameters (bringup --config)": ["bringup", "--config", "{f}", "--bag", "{out}"],
}


# the fast tier: every kind of bomb once, and every reader twice
@pytest.mark.fast_cases(
    "20 MB-fin (sweep --fin)",
    "deep nesting-model (sweep --model)",
    "100,000-digit integer-parameters (bringup --config)",
    "python tag-fin (sweep --fin)",
    "aliases-model (sweep --model)",
    "not UTF-8-parameters (bringup --config)",
)
@pytest.mark.parametrize("reader", list(YAML_READERS))
@pytest.mark.parametrize("kind", YAML_KINDS)
def test_no_configuration_file_hangs_or_crashes_a_reader(tmp_path: Path, kind: str, reader: str) -> None:
    f = yaml_bomb(tmp_path / "bad.yaml", kind)
    argv = [a.format(f=f, out=tmp_path / "b.mcap") for a in YAML_READERS[reader]]
    argv[0] = str(BIN / argv[0])
    t0 = time.monotonic()
    run = subprocess.run(
        argv, capture_output=True, text=True, timeout=60, env=clean_env(), stdin=subprocess.DEVNULL
    )
    wall = time.monotonic() - t0
    assert wall < 10.0
    assert run.returncode == 2, run.stdout + run.stderr
    assert "Traceback" not in run.stderr
    errors = [x for x in run.stderr.splitlines() if "error" in x.lower()]
    assert len(errors) == 1 and str(f) in errors[0], run.stderr
    assert not (tmp_path / "b.mcap").exists()


def test_sigterm_stops_bringup_while_it_reads_its_configuration(tmp_path: Path) -> None:
    f = yaml_bomb(tmp_path / "big.yaml", "20 MB")
    proc = subprocess.Popen(
        [str(BIN / "bringup"), "--config", str(f), "--bag", str(tmp_path / "b.mcap")],
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=clean_env(),
        text=True,
    )
    time.sleep(0.3)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=10)
    assert proc.returncode != 0 or "interrupted" in err
    assert "Traceback" not in err


# ---------------------------------------------------------------------------- outputs kept
def test_diagnose_never_overwrites_its_outputs(tmp_path: Path) -> None:
    out = tmp_path / "findings.json"
    out.write_text("keep me")
    report = tmp_path / "report"
    report.mkdir()
    (report / "report.md").write_text("keep me too")
    for extra in (["--json", str(out)], ["--report", str(report)]):
        t0 = time.monotonic()
        run = subprocess.run(
            [str(BIN / "piezofin"), "diagnose", "--paper", *extra],
            capture_output=True,
            text=True,
            env=clean_env(),
        )
        assert run.returncode == 2
        assert "--force" in run.stderr and "Traceback" not in run.stderr
        assert time.monotonic() - t0 < 10.0  # refused before the work, not after it
    assert out.read_text() == "keep me" and (report / "report.md").read_text() == "keep me too"


def test_recover_leaves_nothing_behind_when_it_fails(tmp_path: Path) -> None:
    src = bomb(tmp_path / "src.mcap", "many chunks, zstd")
    out = tmp_path / "rec.mcap"
    run = subprocess.run(
        [str(BIN / "piezofin"), "bag", "recover", str(src), "-o", str(out)],
        capture_output=True,
        text=True,
        env=clean_env(),
        timeout=60,
    )
    assert run.returncode == 2, run.stderr
    assert not out.exists() and os.listdir(tmp_path) == ["src.mcap"]


# ------------------------------------------------------------------ hostile rosbag2 directories
SAMPLE = Path(__file__).resolve().parents[2] / "bags" / "sample_M8528-P1.mcap"


def bag_directory(d: Path, kind: str) -> tuple[Path, str]:
    """A rosbag2 directory built as an attacker would (issue 29), and the words its refusal says."""
    d.mkdir()
    split = d / "run_0.mcap"
    meta = d / "metadata.yaml"

    def listing(names: list[str], extra: str = "") -> None:
        meta.write_text(
            "rosbag2_bagfile_information:\n  version: 9\n  storage_identifier: mcap\n"
            + "  relative_file_paths:\n"
            + "".join(f"  - {n}\n" for n in names)
            + extra
        )

    if kind == "alias bomb in metadata.yaml":  # 1.4 kB, a billion laughs
        os.symlink(SAMPLE, split)
        laughs = ["  a0: &a0 [x, x, x, x, x, x, x, x, x, x]"]
        laughs += [f"  a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 10) + "]" for i in range(1, 9)]
        listing(["run_0.mcap"], "  junk:\n" + "\n".join(laughs) + "\n")
        return d, "aliases"
    if kind == "40 MB metadata.yaml":
        os.symlink(SAMPLE, split)
        with open(meta, "w") as fh:
            fh.write("rosbag2_bagfile_information:\n  relative_file_paths: [run_0.mcap]\n  junk:\n")
            line = "  - " + "x" * 70 + "\n"
            fh.write(line * (40_000_000 // len(line)))
        return d, "larger than"
    if kind == "a FIFO as a split":
        os.mkfifo(split)
        return d, "not a regular file"
    if kind == "a FIFO listed as a split":
        os.mkfifo(split)
        listing(["run_0.mcap"])
        return d, "not a regular file"
    if kind == "../../../etc/passwd":
        listing(["../../../../../../../etc/passwd"])
        return d, "outside the bag's directory"
    if kind == "/etc/shadow":
        listing(["/etc/shadow"])
        return d, "outside the bag's directory"
    if kind == "a link out of the directory":
        os.symlink("/etc/passwd", split)
        listing(["run_0.mcap"])
        return d, "outside the bag's directory"
    if kind == "a link out, no metadata":
        os.symlink("/etc/passwd", split)
        return d, "outside the bag's directory"
    if kind == "10,000 splits listed":
        listing([f"run_{i}.mcap" for i in range(10_000)])
        return d, "more than 4096"
    if kind == "one split listed 4,096 times":  # (issue 38: 1.85 GB after 353 readings, growing)
        split.write_bytes(b"\x89MCAP0\r\n")  # (refused before it is read)
        listing(["run_0.mcap"] * 4096)
        return d, "more than once"
    if kind == "one split under two names":
        split.write_bytes(b"\x89MCAP0\r\n")
        os.link(split, d / "run_1.mcap")
        listing(["run_0.mcap", "run_1.mcap"])
        return d, "more than once"
    if kind == "a NUL byte in a listed name":
        meta.write_text(
            "rosbag2_bagfile_information:\n  storage_identifier: mcap\n"
            '  relative_file_paths: ["run\\0_0.mcap"]\n'
        )
        return d, "no file name"
    if kind == "a tag in metadata.yaml":
        listing(["run_0.mcap"], "  junk: !!python/object/apply:os.system ['true']\n")
        return d, "tags"
    if kind == "5,000 splits, no metadata":
        for i in range(5000):
            (d / f"run_{i}.mcap").touch()
        return d, "more than 4096"
    raise ValueError(kind)


DIRECTORY_ATTACKS = [
    "alias bomb in metadata.yaml",
    "40 MB metadata.yaml",
    "a FIFO as a split",
    "a FIFO listed as a split",
    "../../../etc/passwd",
    "/etc/shadow",
    "a link out of the directory",
    "a link out, no metadata",
    "10,000 splits listed",
    "5,000 splits, no metadata",
    "one split listed 4,096 times",
    "one split under two names",
    "a NUL byte in a listed name",
    "a tag in metadata.yaml",
]


@pytest.mark.fast_cases("alias bomb in metadata.yaml", "../../../etc/passwd")
@pytest.mark.parametrize("kind", DIRECTORY_ATTACKS)
def test_a_bag_directory_cannot_make_diagnose_hang_blow_up_or_leave_it(tmp_path: Path, kind: str) -> None:
    """`piezofin diagnose DIR`, as the attacker of issue 29 ran it: one error line naming the directory
    and what is wrong, exit 2, within 10 s and 300 MB (before: 1.15 GB and 7.7 GB, hangs on a FIFO,
    /etc/passwd and /etc/shadow opened)."""
    d, words = bag_directory(tmp_path / "bag", kind)
    status, err, wall, peak_mb = run_measured([str(BIN / "piezofin"), "diagnose", str(d)], timeout=60)
    assert wall < 10.0, (wall, err)
    assert status == 2, err
    assert "Traceback" not in err
    errors = [x for x in err.splitlines() if "error" in x.lower()]
    assert len(errors) == 1 and str(d) in errors[0] and words in errors[0], err
    assert peak_mb < 300, peak_mb


@pytest.mark.slow
@pytest.mark.parametrize("shape", ["short scalars", "a rosbag2 files list"])
def test_a_metadata_file_costs_memory_in_proportion_to_its_size(tmp_path: Path, shape: str) -> None:
    """A ``metadata.yaml`` just under the 4 MiB limit (issue 38: 4.19 MB took 1.27 GB and 101 s,
    about 300x the file): read as events, within 100x its size (plus the interpreter's 200 MB)."""
    d = tmp_path / "bag"
    d.mkdir()
    (d / "run_0.mcap").write_bytes(SAMPLE.read_bytes())
    head = "rosbag2_bagfile_information:\n  storage_identifier: mcap\n  relative_file_paths: [run_0.mcap]\n"
    if shape == "short scalars":
        body = "  junk: [" + "1, " * ((4_190_000 - len(head)) // 3) + "1]\n"
    else:
        entry = (
            "    - path: run_{i}.mcap\n      duration: {{nanoseconds: 1000000}}\n      message_count: 100\n"
        )
        n = (4_190_000 - len(head)) // len(entry.format(i=100000))
        body = "  files:\n" + "".join(entry.format(i=i) for i in range(n))
    (d / "metadata.yaml").write_text(head + body)
    size_mb = (d / "metadata.yaml").stat().st_size / 1e6
    status, err, wall, peak_mb = run_measured([str(BIN / "piezofin"), "estimate", str(d)], timeout=120)
    print(f"{shape}: metadata {size_mb:.2f} MB, status {status}, {wall:.1f} s, peak {peak_mb:.0f} MB")
    assert status == 0, err[-2000:]
    assert peak_mb <= 100 * size_mb + 200, peak_mb
    assert wall < 30.0, wall


def _in_splits(d: Path, n: int) -> Path:
    """The sample bag written again as a rosbag2 directory of ``n`` splits (no metadata.yaml)."""
    from piezofin_ros.bags import BagWriter, read_messages

    d.mkdir()
    messages = list(read_messages(SAMPLE))
    per = -(-len(messages) // n)
    for k in range(n):
        with BagWriter(d / f"run_{k}.mcap") as bag:
            for m in messages[k * per : (k + 1) * per]:
                if m.topic not in bag.counts:
                    bag.add_topic(m.topic, m.type_name, strict=False)
                bag.write(m.topic, m.log_time_ns, m.data)
    return d


def test_diagnose_reads_each_file_of_a_bag_once(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 29: `diagnose` opened and decoded every bag twice (the estimator's replay, then the noise
    scan); one pass now feeds both."""
    from piezofin_ros.bags import reader
    from piezofin_ros.diagnosis.data import from_bags
    from piezofin_ros.physics.fin import load_fin

    opened: list[str] = []
    real = reader.read_file

    def counting(path, *args, **kwargs):  # type: ignore[no-untyped-def]
        opened.append(Path(path).name)
        return real(path, *args, **kwargs)

    monkeypatch.setattr(reader, "read_file", counting)
    d = _in_splits(tmp_path / "bag", 3)
    opened.clear()
    trials, _ = from_bags([d], load_fin("M8528-P1"))
    assert sorted(opened) == ["run_0.mcap", "run_1.mcap", "run_2.mcap"], opened
    assert len(trials) == 2  # the sample bag: two trials


@pytest.mark.slow
def test_diagnose_says_which_split_it_reads(tmp_path: Path) -> None:
    """Issue 29: 10,000 splits ran past 90 s with nothing said.  A directory of many splits is read
    with its progress on standard error (the first split, the last, and one line every 2 s between),
    and gives the diagnosis the single file gives."""
    d = _in_splits(tmp_path / "bag", 300)
    runs = {}
    for name, bag in (("many", d), ("one", SAMPLE)):
        cmd = [str(BIN / "piezofin"), "diagnose", str(bag), "--json", str(tmp_path / f"{name}.json")]
        runs[name] = subprocess.run(
            cmd, capture_output=True, text=True, timeout=300, stdin=subprocess.DEVNULL
        )
    many, one = runs["many"], runs["one"]
    assert many.returncode == 0 and one.returncode == 0, many.stderr[-2000:] + one.stderr[-2000:]
    assert f"{d}: split 1/300 (run_0.mcap)" in many.stderr, many.stderr[-2000:]
    assert f"{d}: split 300/300 (run_299.mcap)" in many.stderr, many.stderr[-2000:]
    a, b = (json.loads((tmp_path / f"{name}.json").read_text()) for name in ("many", "one"))
    assert a["trials"] == b["trials"] and a["verdict"] == b["verdict"]
