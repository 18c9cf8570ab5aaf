"""Small hostile inputs stay small: decompression bombs in bags end in one line."""

from __future__ import annotations

import bz2
import resource
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace
from typing import TYPE_CHECKING, Any

import pytest
import zstandard
from labbags import PROBE_MAP, Session, probe_messages
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.rosbag2 import StoragePlugin, storage_mcap
from rosbags.rosbag2 import Writer as Ros2Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from recorder import load_objects
from recorder._rigconfig import load_rig_config
from recorder.bagimport._bounded import bz2_bounded, lz4_bounded, zstd_bounded
from recorder.bagimport._ros1 import StreamingReader
from recorder.bagimport._topicmap import load_topic_map
from recorder.errors import BagImportError, CatalogError, RecorderError
from replay.errors import ReplayError
from replay.learning._datasets import declared_novel
from schemas import MAX_TOML_BYTES, MAX_TOML_DEPTH, TomlLimitError, loads_toml
from schemas.cdr import MAX_DECODER_LINES, compile_cdr, compile_ros1

if TYPE_CHECKING:
    from collections.abc import Callable

ROOT = Path(__file__).parents[2]
SMALL = Session(("wood",), ("hold5",), trials=1, execute_s=1.0, gap_s=0.4)
#: 64 MB of zeros compress to a few bytes; streams/frames repeated make gigabytes from kB.
_BLOCK = bytes(64 << 20)
_STREAMS = 64  # 4 GB decompressed, more than the subprocess may allocate
_LIMITED = """
import resource, sys
resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30))
from recorder._cli import main
sys.exit(main(sys.argv[1:]))
"""


def _write(path: Path, writer: Any, *, ros1: bool) -> Path:
    messages, store = probe_messages(ros1=ros1, session=SMALL)
    serialize = store.serialize_ros1 if ros1 else store.serialize_cdr
    with writer:
        connections: dict[str, Any] = {}
        for receive, topic, msgtype, message in sorted(messages, key=lambda m: m[0]):
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(connections[topic], receive, serialize(message, msgtype))
    return path


def _bz2_bomb_bag(path: Path) -> Path:
    """Return a ROS 1 bag whose bz2 chunks each decompress to 4 GB (their headers: kB)."""
    writer = Ros1Writer(path)
    writer.set_compression(Ros1Writer.CompressionFormat.BZ2)
    bomb = bz2.compress(_BLOCK) * _STREAMS
    writer.compressor = lambda _: bomb
    return _write(path, writer, ros1=True)


def _zstd_bomb_bag(path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """Return a ROS 2 MCAP bag whose zstd chunks each decompress to 4 GB."""
    bomb = zstandard.ZstdCompressor().compress(_BLOCK) * _STREAMS
    monkeypatch.setattr(storage_mcap, "zstd", SimpleNamespace(compress=lambda _: bomb))
    writer = Ros2Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    return _write(path, writer, ros1=False)


def test_bounded_decompressors_stop_past_the_limit() -> None:
    lz4 = pytest.importorskip("lz4.frame")
    for bounded, data in (
        (bz2_bounded, bz2.compress(_BLOCK[:4096])),
        (lz4_bounded, lz4.compress(_BLOCK[:4096])),
        (zstd_bounded, zstandard.ZstdCompressor().compress(_BLOCK[:4096])),
    ):
        assert bounded(data, 4096) == _BLOCK[:4096]
        with pytest.raises(Exception, match=r"decompresses to more than 4095 bytes"):
            _ = bounded(data, 4095)


def test_a_ros1_chunk_that_lies_about_its_size_is_refused(tmp_path: Path) -> None:
    bag = _bz2_bomb_bag(tmp_path / "bomb.bag")
    assert bag.stat().st_size < 256 << 10
    with StreamingReader(bag) as reader, pytest.raises(Exception, match="decompresses to more"):
        _ = list(reader.messages())


@pytest.mark.parametrize("kind", ["ros1-bz2", "ros2-zstd"])
def test_decompression_bombs_end_in_one_line_within_bounded_memory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, kind: str
) -> None:
    bag = (
        _bz2_bomb_bag(tmp_path / "bomb.bag")
        if kind == "ros1-bz2"
        else _zstd_bomb_bag(tmp_path / "bomb", monkeypatch)
    )
    topic_map = tmp_path / "map.toml"
    topic_map.write_text(PROBE_MAP, encoding="utf-8")
    argv = ["import-bag", str(bag), "--topic-map", str(topic_map), "--out", str(tmp_path / "o")]
    result = subprocess.run(  # noqa: S603 (this interpreter, a fixed script)
        [sys.executable, "-c", _LIMITED, *argv],
        capture_output=True,
        text=True,
        check=False,
        cwd=ROOT,
        timeout=300,
    )
    assert result.returncode == 1, result.stderr[-2000:]
    assert result.stderr.startswith("atikt-record: error: "), result.stderr[-2000:]
    assert result.stderr.count("\n") == 1, result.stderr[-2000:]
    assert "decompresses to more than" in result.stderr, result.stderr
    assert resource.getrlimit(resource.RLIMIT_AS)[0] != 3 << 30  # only the subprocess


@pytest.mark.parametrize("compile_", [compile_ros1, compile_cdr])
def test_a_type_of_nested_fixed_arrays_is_left_to_rosbags(compile_: Any) -> None:
    store = get_typestore(Stores.ROS2_HUMBLE)
    for name, text in (
        ("hostile/msg/Leaf", "string[8] s"),
        ("hostile/msg/Mid", "hostile/msg/Leaf[64] leaves"),
        ("hostile/msg/Top", "float64 v\nhostile/msg/Mid[64] mids"),  # 32768 strings
    ):
        store.register(get_types_from_msg(text, name))
    assert compile_(store, "hostile/msg/Top", ["v"], stamped=False) is None
    store.register(get_types_from_msg("float64 v\nfloat64[64] w", "hostile/msg/Ok"))
    decoder = compile_(store, "hostile/msg/Ok", ["v"], stamped=False)
    assert decoder is not None
    assert decoder.key.count("\n") < MAX_DECODER_LINES


_DEEP = "a = " + "[" * 50_000 + "]" * 50_000 + "\n"


@pytest.mark.parametrize(
    ("read", "error"),
    [
        (load_objects, CatalogError),
        (load_topic_map, BagImportError),
        (load_rig_config, RecorderError),
        (lambda p: declared_novel(p.parent), ReplayError),
    ],
    ids=["catalog", "topic-map", "rig-config", "objects-toml"],
)
def test_deeply_nested_toml_is_an_error_not_a_recursion(
    tmp_path: Path,
    read: Callable[[Path], object],
    error: type[Exception],
) -> None:
    path = tmp_path / "objects.toml"
    path.write_text(_DEEP, encoding="utf-8")
    with pytest.raises(error, match=r"nested 50000 deep, more than the 32 allowed") as info:
        _ = read(path)
    assert "\n" not in str(info.value)


def test_the_toml_limits_count_only_what_nests() -> None:
    text = "a = \"[[[[{{{{\"\nb = '''[[[[\n]'''\n# [[[[[[\nc = [[1], {x = [2]}]\n"
    assert loads_toml(text)["c"] == [[1], {"x": [2]}]
    with pytest.raises(TomlLimitError, match=r"keys nested 39 deep"):
        _ = loads_toml("a" + ".a" * 39 + " = 1\n")
    with pytest.raises(TomlLimitError, match=r"characters, more than the"):
        _ = loads_toml("#" * (MAX_TOML_BYTES + 1))
    assert loads_toml("a = " + "[" * MAX_TOML_DEPTH + "]" * MAX_TOML_DEPTH)["a"]
