"""The batch messages' bytes (tactile_contact.ros.cdr) against rclpy's own serialization.

Every check goes through rclpy's ``serialize_message`` / ``deserialize_message`` (the rmw's
type support, as DDS sends it): random messages read back field by field, and a broken
buffer refused with the field named.
"""

from __future__ import annotations

import array
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

pytestmark = pytest.mark.ros

names = st.text(st.characters(codec="utf-8", exclude_characters="\x00"), max_size=12)
stamps = st.tuples(st.integers(0, 2**31 - 1), st.integers(0, 999_999_999))


@st.composite
def batches(draw: st.DrawFn) -> dict:
    n = draw(st.integers(0, 6))
    sizes = draw(st.lists(st.integers(0, 40), min_size=n, max_size=n))
    k = sum(sizes)
    return {
        "stamp": draw(stamps),
        "bus": draw(names),
        "patches": draw(st.lists(names, min_size=n, max_size=n)),
        "frame_ids": draw(st.lists(names, min_size=n, max_size=n)),
        "stamps": draw(st.lists(stamps, min_size=n, max_size=n)),
        "offsets": np.concatenate([[0], np.cumsum(sizes)]).astype(int).tolist() if n else [],
        "ids": draw(st.lists(st.integers(0, 65535), min_size=k, max_size=k)),
        "delta_c": draw(st.lists(st.floats(width=32, allow_nan=False), min_size=k, max_size=k)),
        "raw": draw(st.lists(st.integers(0, 255), min_size=k, max_size=k)),
        "status": draw(st.lists(st.integers(0, 255), min_size=k, max_size=k)),
    }


def _batch_message(d: dict):
    from builtin_interfaces.msg import Time

    from tactile_contact.msg import TaxelBatch

    m = TaxelBatch(bus=d["bus"], patches=d["patches"], frame_ids=d["frame_ids"])
    m.header.stamp = Time(sec=d["stamp"][0], nanosec=d["stamp"][1])
    m.stamps = [Time(sec=s, nanosec=ns) for s, ns in d["stamps"]]
    m.offsets = array.array("I", d["offsets"])
    m.taxel_ids = array.array("H", d["ids"])
    m.delta_c = array.array("f", d["delta_c"])
    m.raw = array.array("B", d["raw"])
    m.status = array.array("B", d["status"])
    return m


@given(batches())
def test_a_taxel_batch_reads_as_rclpy_wrote_it(d: dict) -> None:
    from rclpy.serialization import serialize_message

    from tactile_contact.ros.cdr import read_taxel_batch

    v = read_taxel_batch(serialize_message(_batch_message(d)))
    assert v.stamp_ns == d["stamp"][0] * 10**9 + d["stamp"][1]
    assert (v.bus, v.patches, v.frame_ids) == (d["bus"], d["patches"], d["frame_ids"])
    assert v.stamps_ns == [s * 10**9 + ns for s, ns in d["stamps"]]
    assert list(v.offsets) == d["offsets"]
    assert v.taxel_ids.tolist() == d["ids"]
    assert v.delta_c.tolist() == np.float32(d["delta_c"]).tolist()
    assert v.raw.tolist() == d["raw"] and v.status.tolist() == d["status"]


@given(st.text(max_size=10), st.lists(st.integers(0, 65535), max_size=30))
def test_a_taxel_array_reads_as_rclpy_wrote_it(patch: str, ids: list[int]) -> None:
    from rclpy.serialization import serialize_message

    from tactile_contact.msg import TaxelArray
    from tactile_contact.ros.cdr import read_taxel_array

    m = TaxelArray(patch=patch.replace("\x00", ""))
    m.header.frame_id = "skin"
    m.header.stamp.sec, m.header.stamp.nanosec = 1_700_000_000, 123
    m.taxel_ids = array.array("H", ids)
    m.delta_c = array.array("f", [1e-15 * i for i in range(len(ids))])
    m.raw = array.array("B", [i % 256 for i in range(len(ids))])
    m.status = array.array("B", [1] * len(ids))
    v = read_taxel_array(serialize_message(m))
    assert (v.patch, v.frame_id, v.stamp_ns) == (m.patch, "skin", 1_700_000_000 * 10**9 + 123)
    assert v.taxel_ids.tolist() == ids and v.raw.tolist() == list(m.raw)
    assert v.delta_c.tolist() == list(m.delta_c) and v.status.tolist() == [1] * len(ids)


@st.composite
def contact_rows(draw: st.DrawFn):
    from tactile_contact.ros.cdr import ContactRows

    p = draw(st.integers(0, 6))
    c = draw(st.integers(0, 6)) if p else 0
    fl = st.floats(-1e6, 1e6, allow_nan=False)

    def floats(n: int) -> list[float]:
        return draw(st.lists(fl, min_size=n, max_size=n))

    return ContactRows(
        patches=draw(st.lists(names, min_size=p, max_size=p)),
        frame_ids=draw(st.lists(names, min_size=p, max_size=p)),
        stamps_ns=[s * 10**9 + ns for s, ns in draw(st.lists(stamps, min_size=p, max_size=p))],
        states=draw(st.lists(st.integers(0, 3), min_size=p, max_size=p)),
        total_force=floats(p),
        cop_x=floats(p),
        cop_y=floats(p),
        latency=floats(p),
        force=floats(c),
        center=[tuple(floats(3)) for _ in range(c)],
        radius=floats(c),
        profile=draw(
            st.lists(st.sampled_from(["punch", "hertz", "field", ""]), min_size=c, max_size=c)
        ),
        contact_patch=draw(st.lists(st.integers(0, max(p - 1, 0)), min_size=c, max_size=c)),
    )


@given(contact_rows(), stamps, names)
def test_a_contact_array_written_here_reads_in_rclpy(rows, stamp, worker: str) -> None:
    from rclpy.serialization import deserialize_message

    from tactile_contact.msg import ContactArray
    from tactile_contact.ros.cdr import write_contact_array

    m = deserialize_message(
        write_contact_array(stamp[0] * 10**9 + stamp[1], worker, rows), ContactArray
    )
    assert (m.header.stamp.sec, m.header.stamp.nanosec, m.header.frame_id) == (*stamp, "")
    assert m.worker == worker and list(m.patches) == rows.patches
    assert list(m.frame_ids) == rows.frame_ids
    assert [t.sec * 10**9 + t.nanosec for t in m.stamps] == rows.stamps_ns
    assert list(m.states) == rows.states
    for name in ("total_force", "cop_x", "cop_y", "latency"):
        assert list(getattr(m, name)) == getattr(rows, name), name
    assert [c.force for c in m.contacts] == rows.force
    assert [(c.center.x, c.center.y, c.center.z) for c in m.contacts] == rows.center
    assert [c.radius for c in m.contacts] == rows.radius
    assert [c.profile for c in m.contacts] == rows.profile
    assert list(m.contact_patch) == rows.contact_patch


def test_what_cannot_be_a_message_is_refused_with_the_field_named() -> None:
    from rclpy.serialization import serialize_message

    from tactile_contact.ros.cdr import CdrError, ContactRows, read_taxel_batch, write_contact_array

    good = serialize_message(
        _batch_message(
            {
                "stamp": (1, 2),
                "bus": "can0",
                "patches": ["a"],
                "frame_ids": ["fa"],
                "stamps": [(3, 4)],
                "offsets": [0, 2],
                "ids": [1, 2],
                "delta_c": [0.0, 1.0],
                "raw": [1, 2],
                "status": [0, 0],
            }
        )
    )
    assert read_taxel_batch(good).patches == ["a"]
    with pytest.raises(CdrError, match=r"TaxelBatch: truncated or malformed"):
        read_taxel_batch(good[:-2])
    with pytest.raises(CdrError, match="not little-endian CDR"):
        read_taxel_batch(b"\x00\x00\x00\x00" + good[4:])
    with pytest.raises(CdrError, match="not little-endian CDR"):
        read_taxel_batch(b"")
    rows = ContactRows(["a"], ["fa"], [0], [1], [1.0], [0.0], [0.0], [math.nan])
    with pytest.raises(ValueError, match="non-finite"):
        write_contact_array(0, "w", rows)
    rows.latency = [1.0, 2.0]
    with pytest.raises(ValueError, match=r"1 patches and 0 contacts, but per-patch lengths"):
        write_contact_array(0, "w", rows)


@given(batches())
def test_a_taxel_batch_written_here_reads_in_rclpy(d: dict) -> None:
    from rclpy.serialization import deserialize_message, serialize_message

    from tactile_contact.msg import TaxelBatch
    from tactile_contact.ros.cdr import write_taxel_batch

    cuts = list(zip(d["offsets"][:-1], d["offsets"][1:], strict=True))
    data = write_taxel_batch(
        d["stamp"][0] * 10**9 + d["stamp"][1],
        d["bus"],
        d["patches"],
        d["frame_ids"],
        [s * 10**9 + ns for s, ns in d["stamps"]],
        *(
            [np.asarray(d[key], dtype=dt)[a:b] for a, b in cuts]
            for key, dt in (("ids", "u2"), ("delta_c", "f4"), ("raw", "u1"), ("status", "u1"))
        ),
    )
    expected = _batch_message(d)
    if not d["patches"]:
        expected.offsets = array.array("I", [0])  # (written: [0]; rclpy's own may be [])
    assert deserialize_message(data, TaxelBatch) == expected
    # (not byte for byte: the rmw leaves its padding bytes as it found them)
    assert len(data) == len(serialize_message(expected))


@given(contact_rows(), stamps, names)
def test_a_contact_array_reads_back_as_written_and_as_rclpy_wrote_it(
    rows, stamp, worker: str
) -> None:
    from rclpy.serialization import deserialize_message, serialize_message

    from tactile_contact.msg import ContactArray
    from tactile_contact.ros.cdr import read_contact_array, write_contact_array

    data = write_contact_array(stamp[0] * 10**9 + stamp[1], worker, rows)
    got_worker, got = read_contact_array(data)
    assert got_worker == worker and got == rows
    # and from the rmw's own bytes of the same message
    assert read_contact_array(serialize_message(deserialize_message(data, ContactArray))) == (
        worker,
        rows,
    )


def test_batches_whose_names_differ_after_their_first_bytes_read_each_their_own() -> None:
    """read_taxel_batch keeps the names of the batches it read lately (the same a bus's
    every period), looked up by their first bytes: batches that share those (a long bus
    name) and differ after them read each their own names, in any order, and a batch cut
    inside its names is refused though one with those first bytes was read before."""
    from rclpy.serialization import serialize_message

    from tactile_contact.ros.cdr import CdrError, read_taxel_batch

    def batch(patches: list[str], frame_ids: list[str]) -> bytes:
        d = {
            "stamp": (1, 2),
            "bus": "a_bus_whose_name_is_longer_than_the_bytes_the_names_are_looked_up_by",
            "patches": patches,
            "frame_ids": frame_ids,
            "stamps": [(3, 4)] * len(patches),
            "offsets": list(range(len(patches) + 1)),
            "ids": list(range(len(patches))),
            "delta_c": [0.5] * len(patches),
            "raw": [1] * len(patches),
            "status": [0] * len(patches),
        }
        return serialize_message(_batch_message(d))

    one = batch(["hand", "arm"], ["f_hand", "f_arm"])
    other = batch(["hand", "leg"], ["f_hand", "f_leg"])
    longer = batch(["hand", "arm", "leg"], ["f_hand", "f_arm", "f_leg"])
    assert one[:80] == other[:80]  # (the same first bytes, past the lookup's key)
    for data, want in [(one, "arm"), (other, "leg"), (one, "arm"), (longer, "arm")] * 2:
        v = read_taxel_batch(data)
        assert v.patches[1] == want and v.frame_ids[1] == f"f_{want}"
        assert len(v.patches) == len(v.offsets) - 1 == len(v.taxel_ids)
    v.patches.append("mine")  # (the caller's own list: the next read is unchanged)
    assert read_taxel_batch(longer).patches == ["hand", "arm", "leg"]
    with pytest.raises(CdrError, match=r"TaxelBatch: truncated or malformed"):
        read_taxel_batch(one[: one.index(b"f_arm")])
