"""MCAP writing checked by an independent reader (rosbags), and clear errors on bad files."""

from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from piezofin_ros.bags import BagError, BagWriter, block_of, read_messages, typestore
from piezofin_ros.bags.blocks import Block, to_layout


def cdr_block(block: Block) -> bytes:
    store = typestore()
    dims, data = to_layout(block)
    Dim = store.types["std_msgs/msg/MultiArrayDimension"]
    Layout = store.types["std_msgs/msg/MultiArrayLayout"]
    Msg = store.types["std_msgs/msg/Float64MultiArray"]
    msg = Msg(
        layout=Layout(dim=[Dim(label=a, size=b, stride=c) for a, b, c in dims], data_offset=0), data=data
    )
    return bytes(store.serialize_cdr(msg, "std_msgs/msg/Float64MultiArray"))


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_rosbags_reads_every_message(tmp_path: Path, compression: str) -> None:
    path = tmp_path / "run.mcap"
    blocks = [Block.from_columns(t_s=k + np.arange(10) / 10, voltage_V=np.full(10, k)) for k in range(300)]
    with BagWriter(path, compression=compression, chunk_size=4096, flush_s=0.5) as bag:
        bag.add_topic("/fin/drive", "std_msgs/msg/Float64MultiArray")
        bag.add_topic("/note", "std_msgs/String")
        for k, b in enumerate(blocks):
            bag.write("/fin/drive", int(k * 1e8), cdr_block(b))
        bag.write(
            "/note",
            5,
            bytes(
                typestore().serialize_cdr(
                    typestore().types["std_msgs/msg/String"](data="hi"), "std_msgs/msg/String"
                )
            ),
        )
    with AnyReader([path]) as reader:
        assert {c.topic: c.msgtype for c in reader.connections} == {
            "/fin/drive": "std_msgs/msg/Float64MultiArray",
            "/note": "std_msgs/msg/String",
        }
        got = [(c.topic, t, reader.deserialize(raw, c.msgtype)) for c, t, raw in reader.messages()]
    drive = [m for topic, _, m in got if topic == "/fin/drive"]
    assert len(drive) == 300
    np.testing.assert_array_equal(drive[123].data[10:], np.full(10, 123.0))
    assert [t for topic, t, _ in got if topic == "/fin/drive"] == [int(k * 1e8) for k in range(300)]
    # Our own reader agrees, and decodes blocks.
    ours = list(read_messages(path, ["/fin/drive"]))
    assert block_of(ours[7].type_name, ours[7].data)["voltage_V"][0] == 7.0


def test_writer_never_overwrites_and_close_is_idempotent(tmp_path: Path) -> None:
    path = tmp_path / "a.mcap"
    bag = BagWriter(path)
    bag.close()
    bag.close()
    with pytest.raises(FileExistsError):
        BagWriter(path)


@pytest.mark.parametrize(
    ("content", "match"),
    [
        (None, "no such file"),
        (b"", "not a readable MCAP"),
        (b"hello world, not a bag", "not a readable MCAP"),
    ],
)
def test_bad_files_give_one_clear_error(tmp_path: Path, content: bytes | None, match: str) -> None:
    path = tmp_path / "bad.mcap"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(BagError, match=match) as info:
        list(read_messages(path))
    assert str(path) in str(info.value)


def test_a_killed_writer_leaves_rosbag2_metadata_and_recover_keeps_the_qos(tmp_path: Path) -> None:
    """The QoS strings are version 9 (policy names): a file must say so even if its writer never
    closed it, or rosbag2 would decode them as version 8 (integers) and fail."""
    import yaml
    from mcap.exceptions import EndOfFile
    from mcap.records import Metadata
    from mcap.stream_reader import StreamReader

    from piezofin_ros.bags import qos_profile, recover

    path = tmp_path / "killed.mcap"
    bag = BagWriter(path, flush_s=1e-9)
    offered = [qos_profile(reliability="best_effort", depth=1)]
    bag.add_topic("/fin/drive", "std_msgs/msg/Float64MultiArray", offered)
    for k in range(5):
        bag.write("/fin/drive", k, cdr_block(Block.from_columns(t_s=[k], voltage_V=[1.0])))
    bag.abandon()  # as SIGKILL leaves it: no summary, no closing metadata
    early = []
    with open(path, "rb") as f, contextlib.suppress(EndOfFile):  # the cut
        for r in StreamReader(f, skip_magic=False).records:
            if isinstance(r, Metadata) and r.name == "rosbag2":
                early.append(r)
    assert [yaml.safe_load(r.metadata["serialized_metadata"])["version"] for r in early] == [9]
    out = recover(path).output
    msgs = list(read_messages(out))
    assert len(msgs) == 5 and yaml.safe_load(msgs[0].offered_qos) == offered
    from mcap.reader import make_reader

    with open(out, "rb") as f:
        meta = [m for m in make_reader(f).iter_metadata() if m.name == "rosbag2"][-1]
    doc = yaml.safe_load(meta.metadata["serialized_metadata"])
    assert doc["relative_file_paths"] == [out.name] and doc["message_count"] == 5
    assert doc["topics_with_message_count"][0]["topic_metadata"]["offered_qos_profiles"] == offered
