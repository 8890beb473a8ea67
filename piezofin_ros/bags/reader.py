"""Reading bags: every intact message of an MCAP file, whatever happened to it.

:func:`read_messages` streams messages with the ``mcap`` stream reader; damage (a writer killed
before closing, flipped bytes, a truncated chunk) ends a stretch, is reported as a :class:`Damage`
and reading resumes at the next intact chunk, with a budget on memory (a 2 MB file never takes
gigabytes).  :func:`bag_topics` lists the channels from the summary or, without one, by reading."""

from __future__ import annotations

import io
import logging
import math
import mmap
import os
import re
import struct
import time
import zlib
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import lz4.frame
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import EndOfFile, McapError, RecordLengthLimitExceeded
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Message, Schema
from mcap.stream_reader import StreamReader

from ..errors import BagError
from ..files import check_regular, open_regular
from ..physics.fin import config_dir

MCAP_MAGIC = b"\x89MCAP0\r\n"

#: What mcap's reader and the decompressors raise on damaged bytes: mcap's own errors (bad magic,
#: end of file, record length, CRC is a ValueError), struct and EOF errors from truncated records,
#: zstandard's and lz4's (a RuntimeError) decompression errors, and the lookup, arithmetic and type
#: errors that garbled lengths and opcodes cause inside the parser, and the OS's refusal of a seek
#: that a garbled offset asks for (before the start of a truncated file).  Anything else is a bug.
_DAMAGE: tuple[type[BaseException], ...] = (
    McapError,
    ValueError,
    struct.error,
    EOFError,
    zstandard.ZstdError,
    RuntimeError,
    LookupError,
    ArithmeticError,
    TypeError,
    MemoryError,
    OSError,
)


@dataclass(frozen=True)
class BagMessage:
    topic: str
    type_name: str
    log_time_ns: int
    data: bytes
    offered_qos: str = ""  # the channel's offered_qos_profiles


@dataclass(frozen=True)
class Damage:
    """Where and why a bag stops being readable (or a chunk of it is skipped)."""

    path: Path
    offset: int  # byte offset of the damaged record
    size: int  # file size, bytes
    reason: str
    messages_before: int  # messages read before this point
    fatal: bool  # True: nothing after ``offset`` could be read

    def __str__(self) -> str:
        what = "the rest is unreadable" if self.fatal else "this chunk was skipped, reading went on"
        return (
            f"{self.path}: damaged at byte {self.offset} of {self.size} ({self.reason}); {what}; "
            f"{self.messages_before} messages read before it"
        )


_LOG = logging.getLogger(__name__)


def _warn(damage: Damage) -> None:
    _LOG.warning("warning: %s", damage)


#: What a rosbag2 directory may ask a reader for: its ``metadata.yaml`` is refused above this size
#: (rosbag2 writes a few kB, plus about 60 bytes per split), and it may list at most this many splits.
MAX_METADATA_BYTES = 4 * 1024 * 1024
MAX_SPLITS = 4096
#: A directory's reading says which split it is at no more often than this, s.
PROGRESS_S = 2.0


class MetadataError(BagError, ValueError):
    """A rosbag2 ``metadata.yaml`` that is not read (too large, not YAML, aliases, unsafe tags)."""


def resolve_bag(path: str | os.PathLike[str]) -> str:
    """``path`` itself, or, when it does not exist and is relative, the same path in the package's
    share directory: ``bags/sample_M8528-P1.mcap`` works from a colcon workspace (where the install
    puts the sample) as from the repository."""
    text = str(path)
    if os.path.exists(text) or os.path.isabs(text):
        return text
    try:
        installed = config_dir().parent / text
    except FileNotFoundError:
        return text
    return str(installed) if installed.exists() else text


def bag_files(path: str | os.PathLike[str]) -> list[Path]:
    """The MCAP files of a bag: the file itself, or those of a rosbag2 directory.

    A rosbag2 directory lists its files, in recording order, under
    ``rosbag2_bagfile_information.relative_file_paths`` of its ``metadata.yaml``; without a metadata
    file, every ``*.mcap`` in it is read in name order (rosbag2 numbers its splits ``<name>_0.mcap``,
    ``<name>_1.mcap``, ...).  Raises :class:`BagError` naming the directory when it holds no MCAP
    file, its metadata names another storage (sqlite3), a missing file, a file outside the directory
    (``../``, an absolute path, a symbolic link leading out) or something that is not a regular file
    (a FIFO would block the reader), or lists more than :data:`MAX_SPLITS` files; and
    :class:`MetadataError` when ``metadata.yaml`` is larger than :data:`MAX_METADATA_BYTES`, not
    YAML, or uses aliases or tags (no "billion laughs"), or lists a split twice.
    """
    path = Path(path)
    if not path.is_dir():
        return [check_regular(path, BagError)]  # a FIFO or a device: refused before any reading
    listed: list[Path] = []
    meta = path / "metadata.yaml"
    if meta.exists():
        if not meta.is_file():
            raise BagError(f"{meta}: not a regular file")
        storage, names = _rosbag2_listing(meta)
        if storage != "mcap":
            raise BagError(f"{path}: a rosbag2 directory in {storage!r} storage; only mcap is read")
        listed = [_inside(path, n) for n in names]
        missing = [p.name for p in listed if not p.exists()]
        if missing:
            raise BagError(f"{path}: metadata.yaml lists {', '.join(missing)}, which the directory lacks")
    if not listed:  # no metadata, or one that lists no file: the directory's splits by name
        found = sorted(path.glob("*.mcap"), key=_split_order)
        if len(found) > MAX_SPLITS:
            raise BagError(f"{path}: {len(found)} .mcap files, more than {MAX_SPLITS} splits")
        listed = [_inside(path, p.name) for p in found]
    seen: dict[tuple[int, int], str] = {}
    for p in listed:
        if p.exists() and not p.is_file():
            raise BagError(f"{path}: {p.name} is not a regular file (a FIFO or a device is not a split)")
        st = p.stat()
        key = (st.st_dev, st.st_ino)
        if key in seen:  # one split read again and again (listed 4,096 times: 1.85 GB after 353 readings)
            again = p.name if seen[key] == p.name else f"{p.name} (the file {seen[key]} again)"
            raise BagError(f"{path}: metadata.yaml lists {again} more than once: not a rosbag2 bag")
        seen[key] = p.name
    if not listed:
        raise BagError(f"{path}: a directory with no .mcap file (not a rosbag2 bag)")
    return listed


_INFO, _STORAGE, _PATHS = "rosbag2_bagfile_information", "storage_identifier", "relative_file_paths"


def _line(event: Any) -> str:
    mark = getattr(event, "start_mark", None)
    return str(mark.line + 1) if mark is not None else "?"


def _rosbag2_listing(meta: Path) -> tuple[str, list[str]]:
    """``(storage_identifier, relative_file_paths)`` of a rosbag2 ``metadata.yaml``, read as a stream
    of YAML events (libyaml's parser where PyYAML has it): nothing but these two is kept, so memory
    stays within a few times the file whatever it holds (composed whole, a 4.19 MB file of short
    scalars took 955 MB and 28 s; read as events, 21 MB and 0.8 s).  Aliases and explicit tags are
    refused as they come; a listing longer than :data:`MAX_SPLITS` as soon as it is."""
    import yaml

    with open_regular(meta, MetadataError) as fh:
        raw = fh.read(MAX_METADATA_BYTES + 1)
    if len(raw) > MAX_METADATA_BYTES:
        raise MetadataError(
            f"{meta}: larger than {MAX_METADATA_BYTES // 1024} KiB, not a rosbag2 metadata file"
        )
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise MetadataError(f"{meta}: not a text (UTF-8) file") from None
    loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
    # the stack of open collections: [kind, key path of the collection, expecting a key, last key]
    stack: list[list[Any]] = []
    storage, names = "mcap", []

    def where() -> tuple[Any, ...]:
        """The key path of the value the next event is, or None while a mapping expects its key."""
        if not stack:
            return ()
        kind, prefix, expect_key, key = stack[-1]
        if kind == "map":
            return None if expect_key else (*prefix, key)  # type: ignore[return-value]
        return (*prefix, "-")

    def done_value() -> None:
        if stack and stack[-1][0] == "map":
            stack[-1][2] = True

    try:
        for event in yaml.parse(text, Loader=loader):
            if isinstance(event, yaml.AliasEvent):
                raise MetadataError(f"{meta}: aliases (*name) are not accepted (line {_line(event)})")
            tag = getattr(event, "tag", None)
            if tag is not None and not (isinstance(event, yaml.ScalarEvent) and tag == "!"):
                raise MetadataError(f"{meta}: tags ({tag}) are not accepted (line {_line(event)})")
            if isinstance(event, yaml.ScalarEvent):
                at = where()
                if at is None:  # a mapping's key
                    stack[-1][3], stack[-1][2] = event.value, False
                    continue
                if at == (_INFO, _STORAGE):
                    storage = event.value
                elif at == (_INFO, _PATHS, "-"):
                    names.append(event.value)
                    if len(names) > MAX_SPLITS:
                        raise BagError(f"{meta.parent}: metadata.yaml lists more than {MAX_SPLITS} files")
                done_value()
            elif isinstance(event, (yaml.MappingStartEvent, yaml.SequenceStartEvent)):
                at = where()
                kind = "map" if isinstance(event, yaml.MappingStartEvent) else "seq"
                stack.append([kind, at if at is not None else ("?",), True, None])
            elif isinstance(event, (yaml.MappingEndEvent, yaml.SequenceEndEvent)):
                stack.pop()
                done_value()
    except yaml.YAMLError as exc:
        raise MetadataError(f"{meta}: not valid YAML ({' '.join(str(exc).split())})") from None
    return str(storage), [str(n) for n in names]


def _inside(directory: Path, name: str) -> Path:
    """``directory / name``, refused when it leads out of the directory (``..``, absolute, a link)."""
    if "\0" in name or not name:
        raise BagError(f"{directory}: metadata.yaml lists {name!r}, which is no file name")
    p = directory / name
    if not p.resolve().is_relative_to(directory.resolve()):
        raise BagError(f"{directory}: {name!r} leads outside the bag's directory: not read")
    return p


def _split_order(p: Path) -> tuple[str, int]:
    """``run_10.mcap`` after ``run_9.mcap`` (rosbag2's split numbering), else by name."""
    m = re.fullmatch(r"(.*)_(\d+)", p.stem)
    return (m.group(1), int(m.group(2))) if m else (p.stem, -1)


def read_messages(
    path: str | os.PathLike[str],
    topics: Iterable[str] | None = None,
    on_damage: Callable[[Damage], None] | None = _warn,
    progress: Callable[[str], None] | None = None,
) -> Iterator[BagMessage]:
    """Serialised messages of a bag, optionally only ``topics``: an MCAP file, or a rosbag2
    directory (its files in recording order, :func:`bag_files`), each as :func:`read_file` reads it.
    ``progress`` hears which split of a directory is being read (the first, then at most one line
    every :data:`PROGRESS_S` seconds, and the last)."""
    files = bag_files(path)
    said = -math.inf
    for k, file in enumerate(files, 1):
        now = time.monotonic()
        if progress is not None and len(files) > 1 and (now - said >= PROGRESS_S or k in (1, len(files))):
            progress(f"reading {path}: split {k}/{len(files)} ({file.name})")
            said = now
        yield from read_file(file, topics, on_damage)


def read_file(
    path: str | os.PathLike[str],
    topics: Iterable[str] | None = None,
    on_damage: Callable[[Damage], None] | None = _warn,
) -> Iterator[BagMessage]:
    """Serialised messages of one MCAP file in file (recording) order, optionally only ``topics``.

    The file is read record by record, so a damaged bag gives everything it still holds: a file
    whose writer was killed (no summary, a cut chunk) gives everything before the cut; a chunk
    that fails its CRC or does not decompress is skipped; after a cut, garbled, deleted or
    duplicated byte range, reading resumes at the next chunk that passes its CRC (a chunk seen
    before is not read twice).  Channels whose definition was lost with a chunk are taken from
    the file's summary when it is intact.  Each damage is passed to ``on_damage`` (default: a
    logged warning).  Raises :class:`BagError` naming the file when it is missing, not an MCAP
    file, or has no readable message.
    """
    path = Path(path)
    wanted = set(topics) if topics is not None else None
    f = open_regular(path, BagError)  # (missing, a directory, a FIFO, a NUL byte: one BagError)
    with f:
        size = os.fstat(f.fileno()).st_size
        if size == 0:
            raise BagError(f"{path}: not a readable MCAP file (empty)")
        seen_chunks: set[tuple[int, int, int, int]] = set()
        base: int | None = 0  # where the current reader starts
        if f.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            # a damaged start: an MCAP file only if a chunk further on passes its CRC
            base = _next_chunk(f, 0, size, seen_chunks)
            if base is None:
                raise BagError(f"{path}: not a readable MCAP file (no MCAP magic at the start)")
        schemas: dict[int, str] = {}
        channels: dict[int, tuple[str, int]] = {}
        qos: dict[int, str] = {}
        budget = _Budget(path, size)
        summary_channels = _summary_channels(f)
        n = 0
        offset = 0
        first_damage: str | None = None

        def damaged(reason: str, fatal: bool) -> None:
            nonlocal first_damage
            first_damage = first_damage or f"{reason} at byte {offset}"
            if on_damage is not None:
                on_damage(Damage(path, offset, size, reason, n, fatal))

        def take(record: Any) -> BagMessage | None:
            if isinstance(record, Schema):
                schemas[record.id] = record.name
            elif isinstance(record, Channel):
                channels[record.id] = (record.topic, record.schema_id)
                qos[record.id] = record.metadata.get("offered_qos_profiles", "")
            elif isinstance(record, (Message, _LazyMessage)):
                ch = channels.get(record.channel_id)
                name = None
                if ch is not None:
                    name = schemas.get(ch[1], "")
                elif record.channel_id in summary_channels:
                    ch, name, qos[record.channel_id] = summary_channels[record.channel_id]
                if ch is not None and (wanted is None or ch[0] in wanted):
                    q = qos.get(record.channel_id, "")
                    return BagMessage(ch[0], name or "", record.log_time, bytes(record.data), q)
            return None

        if base:
            damaged(f"no MCAP magic at the start; resumed at the first intact chunk, byte {base}", False)
        while base is not None:
            f.seek(base)
            reader = StreamReader(f, skip_magic=base > 0, emit_chunks=True, record_size_limit=size)
            records = iter(reader.records)
            resume: int | None = None
            while True:
                offset = base + _position(reader)
                try:
                    record = next(records)
                except StopIteration:
                    break
                except _DAMAGE as exc:  # any corruption ends this stretch, never the caller
                    resume = _next_chunk(f, offset + 1, size, seen_chunks)
                    if resume is None:
                        damaged(_why(exc), fatal=True)
                    else:
                        damaged(f"{_why(exc)}; resumed at the next intact chunk, byte {resume}", fatal=False)
                    break
                if isinstance(record, Chunk):
                    key = _chunk_key(record)
                    if key in seen_chunks:
                        damaged("chunk: a copy of one already read (duplicated bytes), skipped", fatal=False)
                        continue
                    try:
                        data = budget.expand(record)
                    except _ChunkError as exc:  # size, CRC, zstd, lz4: skip this chunk
                        damaged(f"chunk: {exc}", fatal=False)
                        continue
                    seen_chunks.add(key)
                    try:
                        for r in _chunk_records(data, budget):
                            m = take(r)
                            if m is not None:
                                n += 1
                                yield m
                    except _ChunkError as exc:  # framing inside a chunk that passed its CRC
                        damaged(f"chunk: {exc}", fatal=False)
                    del data
                else:
                    budget.count_record()
                    m = take(record)
                    if m is not None:
                        n += 1
                        yield m
            base = resume
        if n == 0 and first_damage is not None:
            raise BagError(f"{path}: not a readable MCAP file ({first_damage})")


def _chunk_key(chunk: Chunk) -> tuple[int, int, int, int]:
    return (chunk.message_start_time, chunk.message_end_time, chunk.uncompressed_size, chunk.uncompressed_crc)


def _next_chunk(f: BinaryIO, start: int, size: int, seen: set[tuple[int, int, int, int]]) -> int | None:
    """Offset of the first record at or after ``start`` that is a chunk passing its CRC (and not one
    already read), or None.  Chunk records begin with opcode 0x06 and a little-endian u64 length."""
    with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
        pos = start - 1
        while True:
            pos = data.find(b"\x06", pos + 1)
            if pos < 0 or pos + 9 > size:
                return None
            length = int.from_bytes(data[pos + 1 : pos + 9], "little")
            if not 40 <= length <= size - pos - 9:
                continue
            try:
                raw = io.BytesIO(data[pos : pos + 9 + length])
                record = next(iter(StreamReader(raw, skip_magic=True, emit_chunks=True).records))
                if not isinstance(record, Chunk) or not record.uncompressed_crc:
                    continue
                if _chunk_key(record) in seen:
                    continue
                _Budget(Path(), size).expand(record)  # size, CRC, decompression: a real chunk?
            except (_ChunkError, McapError, ValueError, struct.error, EOFError):  # not a chunk: look on
                continue
            return pos


def _summary_channels(f: BinaryIO) -> dict[int, tuple[tuple[str, int], str, str]]:
    """Channel id -> ((topic, schema id), schema name, offered QoS) from the summary, if the file
    has an intact one."""
    try:
        f.seek(0)
        summary = make_reader(f).get_summary()
    except _DAMAGE:  # no summary (a killed writer) or a damaged one: channels come from the chunks
        return {}
    finally:
        f.seek(0)
    if summary is None:
        return {}
    names = {sid: s.name for sid, s in summary.schemas.items()}
    return {
        cid: ((c.topic, c.schema_id), names.get(c.schema_id, ""), c.metadata.get("offered_qos_profiles", ""))
        for cid, c in summary.channels.items()
    }


class _ChunkError(BagError, ValueError):
    """A chunk that cannot be used (its size, CRC, compression or framing); it is skipped."""


@dataclass(frozen=True)
class _LazyMessage:
    """A message record inside a chunk: its bytes are a view into the chunk, copied only if kept."""

    channel_id: int
    log_time: int
    data: memoryview


_MAX_CHUNK = 1 << 30  # bytes: larger uncompressed chunks are corruption, not data


class _Budget:
    """What reading one file may cost, from the file's size and not from what the file claims.

    * one chunk decompresses to at most ``50 x size + 32 MiB`` (and 1 GiB): the bytes are held
      while its records are read, so this bounds the reader's memory (records are parsed one by
      one from the chunk, never expanded into a list);
    * all chunks together to at most ``100 x size + 64 MiB``, and the file holds at most one
      record per 8 bytes (a record takes several compressed bytes even in a very repetitive bag;
      the suite's blocks take about a kilobyte): beyond either, the file is a decompression bomb
      and :class:`BagError` names it.  This bounds the time: a 2 MB file holds at most 250,000
      records.
    """

    def __init__(self, path: Path, size: int) -> None:
        self.path, self.size = path, size
        self.chunk_limit = min(_MAX_CHUNK, 50 * size + (32 << 20))
        self.total_limit = 100 * size + (64 << 20)
        self.record_limit = max(size // 8, 10_000)
        self.expanded = 0
        self.records = 0

    def expand(self, chunk: Chunk) -> bytes:
        """The chunk's records, decompressed (at most its claimed size) and CRC-checked."""
        usize = chunk.uncompressed_size
        if usize > self.chunk_limit:
            raise _ChunkError(f"claims {usize} bytes uncompressed, above the {self.chunk_limit}-byte limit")
        if self.expanded + usize > self.total_limit:
            raise BagError(
                f"{self.path}: expands beyond {self.total_limit} bytes, over 100x its {self.size} bytes: "
                "a decompression bomb, not a bag"
            )
        try:
            if chunk.compression == "zstd":
                with zstandard.ZstdDecompressor().stream_reader(chunk.data) as reader:
                    data = reader.read(usize + 1)
                    while len(data) <= usize:
                        more = reader.read(usize + 1 - len(data))
                        if not more:
                            break
                        data += more
            elif chunk.compression == "lz4":
                data = lz4.frame.LZ4FrameDecompressor().decompress(chunk.data, max_length=usize + 1)
            elif chunk.compression == "":
                data = chunk.data
            else:
                raise _ChunkError(f"unknown compression {chunk.compression!r}")
        except (zstandard.ZstdError, RuntimeError) as exc:  # lz4 raises RuntimeError
            raise _ChunkError(f"does not decompress ({exc})") from None
        if len(data) != usize:
            got = f"more than {usize}" if len(data) > usize else str(len(data))
            raise _ChunkError(f"decompresses to {got} bytes, not the {usize} it states")
        if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
            raise _ChunkError("fails its CRC")
        self.expanded += usize
        return data

    def count_record(self) -> None:
        self.records += 1
        if self.records > self.record_limit:
            raise BagError(
                f"{self.path}: holds more than {self.record_limit} records in {8 * self.record_limit} "
                "bytes: a decompression bomb, not a bag"
            )


def _chunk_records(data: bytes, budget: _Budget) -> Iterator[Schema | Channel | _LazyMessage]:
    """The schema, channel and message records of a decompressed chunk, one at a time."""
    view = memoryview(data)
    pos, end = 0, len(data)
    while pos < end:
        if pos + 9 > end:
            raise _ChunkError(f"a record is cut at byte {pos} of the chunk")
        opcode = data[pos]
        length = int.from_bytes(view[pos + 1 : pos + 9], "little")
        body, pos = pos + 9, pos + 9 + length
        if pos > end:
            raise _ChunkError(f"a record of {length} bytes overruns the chunk")
        budget.count_record()
        if opcode == Opcode.MESSAGE:
            if length < 22:
                raise _ChunkError(f"a message record of {length} bytes (at least 22)")
            channel_id, _, log_time = struct.unpack_from("<HIQ", data, body)
            yield _LazyMessage(channel_id, log_time, view[body + 22 : pos])
        elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
            stream = ReadDataStream(io.BytesIO(view[body:pos]))
            try:
                yield Schema.read(stream) if opcode == Opcode.SCHEMA else Channel.read(stream)
            except (McapError, struct.error, UnicodeDecodeError, EOFError) as exc:
                raise _ChunkError(f"a damaged {Opcode(opcode).name.lower()} record ({exc})") from None


def _position(reader: Any) -> int:
    """Bytes the reader has consumed since it started."""
    return int(reader._stream.count)


def _why(exc: BaseException) -> str:
    name = type(exc).__name__
    if isinstance(exc, (EOFError, struct.error, EndOfFile, RecordLengthLimitExceeded)):
        return "the file ends or is garbled here, as when its writer is stopped before closing it"
    return f"{name}: {exc}" if str(exc) else name


def bag_topics(path: str | os.PathLike[str]) -> dict[str, str]:
    """Topic -> message type of every channel in a bag: from its summary, or (a bag whose writer was
    killed) by reading it through.  Raises :class:`BagError` as :func:`read_messages` does."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            channels = _summary_channels(f)
    except OSError:
        channels = {}
    if channels:
        return {topic: name for (topic, _), name, _ in channels.values()}
    return {m.topic: m.type_name for m in read_messages(path, on_damage=None)}
