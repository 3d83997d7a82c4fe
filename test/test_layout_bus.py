"""Patches on several CAN buses: the layout's ``bus`` key (docs/layout.md, "Buses")."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import yaml

from tactile_contact.model.layout import LayoutError, load_layout, parse_layout

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def doc() -> dict:
    return yaml.safe_load((ROOT / "config" / "hexagon_patch.yaml").read_text())


def _two_patches(doc: dict, first: str, second: str) -> dict:
    other = copy.deepcopy(doc["patches"][0])
    other["name"], other["frame_id"] = "other", "skin_other"
    doc["patches"][0]["bus"] = first
    other["bus"] = second
    doc["patches"].append(other)
    return doc


def test_the_same_can_address_on_two_buses_is_two_modules(doc: dict) -> None:
    layout = parse_layout(_two_patches(doc, "can0", "can1"), "x.yaml")
    assert [p.bus for p in layout.patches] == ["can0", "can1"]
    assert layout.buses() == ("can0", "can1")
    assert (layout.patches[0].taxel_ids() == layout.patches[1].taxel_ids()).all()


def test_the_same_can_address_twice_on_one_bus_is_refused_naming_the_bus(doc: dict) -> None:
    with pytest.raises(
        LayoutError,
        match=r"x\.yaml: patches\[1\]\.modules\[0\]: duplicate CAN address board 0 triangle 0 "
        r"on bus 'can1' \(also in patch 'hexagon'\)",
    ):
        parse_layout(_two_patches(doc, "can1", "can1"), "x.yaml")


@pytest.mark.parametrize("bad", [3, "can 0", "can/0", ["can0"]])
def test_a_bad_bus_name_is_refused(doc: dict, bad: object) -> None:
    doc["patches"][0]["bus"] = bad
    with pytest.raises(LayoutError, match=r"x\.yaml: patches\[0\]\.bus: expected a bus name"):
        parse_layout(doc, "x.yaml")


def test_the_bus_is_wiring_not_physics(doc: dict) -> None:
    # A layout without buses hashes as before (its bundles stay valid), and moving a patch to
    # another bus needs no rebuild: the bus enters neither hash.
    plain = parse_layout(copy.deepcopy(doc)).patches[0]
    assert "bus" not in plain.to_dict() and plain.bus == ""
    doc["patches"][0]["bus"] = "can3"
    wired = parse_layout(doc).patches[0]
    assert wired.to_dict()["bus"] == "can3"
    assert wired.parameter_hash() == plain.parameter_hash()
    assert wired.layout_hash() == plain.layout_hash()
    assert load_layout(ROOT / "config" / "hexagon_patch.yaml").buses() == ("",)
