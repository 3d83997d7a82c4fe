"""Broken bags give one clear error naming the file and the problem, never a traceback.

Each test copies the valid shipped bag (test/data/hexagon_session) to a temporary folder and
breaks one thing: a topic asked for that it lacks, no taxel topic at all, the data file cut
in half, the metadata gone or cut, messages of an older TaxelArray definition (with and
without a recorded type hash). ``tactile-contact replay`` is run in-process (it checks the
bag before any node starts, so no ROS graph is needed) and the library's readers directly.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.msg import get_types_from_msg

from tactile_contact.ros import cli
from tactile_contact.ros.bag import BagError, load_raw, read_messages, typestore

pytestmark = pytest.mark.ros  # (the replay command imports rclpy)

ROOT = Path(__file__).resolve().parents[1]
BAG = ROOT / "test" / "data" / "hexagon_session"
TAXELS = "/hexagon/taxels"

# TaxelArray as an older version had it: no raw values.
OLD_TAXEL_ARRAY = """
std_msgs/Header header
string patch
uint16[] taxel_ids
float32[] delta_c
uint8[] status
"""


def replay(bag: Path, capsys: pytest.CaptureFixture[str], *extra: str) -> str:
    """Run ``tactile-contact replay``; it must fail with exit 1 and one ERROR line."""
    code = cli.main(["replay", str(bag), "--bundles", "/nonexistent", *extra])
    out, err = capsys.readouterr()
    assert code == 1, (out, err)
    assert "Traceback" not in out + err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("ERROR: "), err
    assert str(bag) in lines[0], "the error names the file"
    return lines[0]


@pytest.fixture
def bag(tmp_path: Path) -> Path:
    copy = tmp_path / "session"
    shutil.copytree(BAG, copy)
    return copy


def _rewrite(
    src: Path, dst: Path, *, drop: str = "", old_taxels: bool = False, version: int = 9
) -> None:
    """A copy of ``src`` without topic ``drop``, or with its TaxelArrays in the old form."""
    store = typestore()
    old = get_typestore(Stores.ROS2_KILTED)
    old.register(get_types_from_msg(OLD_TAXEL_ARRAY, "tactile_contact/msg/TaxelArray"))
    with (
        Reader(src) as reader,
        Writer(dst, version=9, storage_plugin=StoragePlugin.MCAP) as w,
    ):
        conns = {}
        for c in reader.connections:
            if c.topic == drop:
                continue
            taxels = old_taxels and c.topic == TAXELS
            conns[c.id] = (
                w.add_connection(c.topic, c.msgtype, typestore=old if taxels else store),
                taxels,
            )
        for c, stamp, data in reader.messages():
            if c.id not in conns:
                continue
            conn, taxels = conns[c.id]
            if taxels:
                m = store.deserialize_cdr(data, c.msgtype)
                Old = old.types[c.msgtype]
                data = old.serialize_cdr(
                    Old(
                        header=m.header,
                        patch=m.patch,
                        taxel_ids=m.taxel_ids,
                        delta_c=m.delta_c,
                        status=m.status,
                    ),
                    c.msgtype,
                )
            w.write(conn, stamp, data)


def test_the_valid_bag_passes_the_checks(bag: Path) -> None:
    raw = load_raw(bag)
    # Every message the bag's index counts (rosbags' own reader), whatever make test-data wrote.
    with Reader(bag) as reader:
        assert len(raw) == reader.message_count > 0
    assert {t for t, *_ in raw} >= {TAXELS}


def test_no_such_bag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert "no such bag" in replay(tmp_path / "nothing", capsys)


def test_a_requested_topic_missing_is_named(bag: Path, capsys: pytest.CaptureFixture[str]) -> None:
    line = replay(bag, capsys, "--topics", TAXELS, "/elbow/taxels")
    assert "/elbow/taxels not in the bag" in line and TAXELS in line  # what it holds


def test_a_bag_without_taxels_says_what_it_holds(
    bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    no_taxels = tmp_path / "no_taxels"
    _rewrite(bag, no_taxels, drop=TAXELS)
    line = replay(no_taxels, capsys)
    assert "no tactile_contact/msg/TaxelArray topic" in line and "/hexagon/contact" in line


def test_a_truncated_data_file(bag: Path, capsys: pytest.CaptureFixture[str]) -> None:
    data = bag / "hexagon_session.mcap"
    os.truncate(data, data.stat().st_size // 2)
    assert "truncated or corrupt" in replay(bag, capsys)
    with pytest.raises(BagError, match="truncated or corrupt"):
        read_messages(bag)


def test_missing_or_cut_metadata(bag: Path, capsys: pytest.CaptureFixture[str]) -> None:
    meta = bag / "metadata.yaml"
    text = meta.read_text()
    meta.write_text(text[: len(text) // 3])
    assert "metadata.yaml unreadable" in replay(bag, capsys)
    meta.unlink()
    assert "no metadata.yaml" in replay(bag, capsys)


@pytest.mark.parametrize("hashed", [True, False], ids=["type-hash", "no-type-hash"])
def test_an_older_message_definition_is_refused(
    bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], hashed: bool
) -> None:
    old = tmp_path / "old"
    _rewrite(bag, old, old_taxels=True)
    if not hashed:  # a bag of a ROS without type hashes (Humble): the messages are decoded
        meta = old / "metadata.yaml"
        lines = meta.read_text().splitlines()
        keep = [ln for ln in lines if "type_description_hash" not in ln and "RIHS01_" not in ln]
        meta.write_text("\n".join(keep) + "\n")
        with Reader(old) as r:
            assert not [c for c in r.connections if c.digest.startswith("RIHS01_")]
    line = replay(old, capsys)
    assert TAXELS in line and "tactile_contact/msg/TaxelArray" in line
    assert ("another definition" in line) or ("do not match" in line)
    with pytest.raises(BagError, match=TAXELS):
        read_messages(old, [TAXELS])
    # The other topics of that bag are still readable on their own.
    assert read_messages(old, ["/hexagon/contact"])
