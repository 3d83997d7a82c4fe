"""The whole-robot layout (config/icub_robot.yaml) and the scenes the simulator plays on it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from tactile_contact.model.layout import load_layout, parse_layout
from tactile_contact.sim.robot_skin import icub_robot, triangle_strip
from tactile_contact.sim.scenes import scene_indentations

ROOT = Path(__file__).resolve().parents[1]
ROBOT = ROOT / "config" / "icub_robot.yaml"


def test_the_shipped_robot_is_what_its_generator_makes() -> None:
    shipped = load_layout(ROBOT)
    made = parse_layout(icub_robot(ROOT / "config"))
    assert [p.to_dict() for p in shipped.patches] == [p.to_dict() for p in made.patches]


def test_the_robot_is_whole_robot_sized_and_its_buses_can_carry_it() -> None:
    layout = load_layout(ROBOT)
    taxels = sum(len(p.taxel_ids()) for p in layout.patches)
    assert len(layout.patches) >= 30 and taxels >= 3000 and len(layout.buses()) >= 3
    for bus in layout.buses():
        modules = sum(len(p.modules) for p in layout.patches if p.bus == bus)
        # two 8-byte frames a module a period, ≈ 125 µs each on a 1 Mbit/s bus, at 50 Hz
        assert modules * 2 * 125e-6 * 50 <= 0.9, f"bus {bus}: {modules} modules"
        boards = {m.board for p in layout.patches if p.bus == bus for m in p.modules}
        assert len(boards) <= 16


def test_the_imported_parts_are_the_robot_files_as_imported() -> None:
    layout = load_layout(ROBOT)
    for name in ("left_forearm_V2.yaml", "left_hand_V2_1.yaml", "left_leg_lower.yaml"):
        for part in load_layout(ROOT / "config" / "icub" / name).patches:
            mine = layout.patch(part.name)
            assert mine.modules == part.modules and mine.surface == part.surface
            right = layout.patch(part.name.replace("left", "right", 1))
            assert right.modules == part.modules and right.bus != mine.bus


def test_a_triangle_strip_tiles_without_gaps_or_overlaps() -> None:
    # The centres of neighbouring triangles are 19.05 mm apart (a side over √3, as in a
    # tiling of equilateral triangles), and every triangle has a neighbour.
    strip = triangle_strip(14, board=3)
    xy = np.array([m["position"] for m in strip])
    d = np.linalg.norm(xy[:, None] - xy[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    assert d.min(axis=1) == pytest.approx(0.033 / np.sqrt(3), abs=1e-5)
    assert [m["triangle"] for m in strip] == list(range(14))


@pytest.mark.parametrize("scene", ["sliding", "typical"])
def test_scenes(scene: str) -> None:
    layout = load_layout(ROBOT)
    patches = list(layout.patches)
    scenes = scene_indentations(patches, scene)
    kinds = [s.kind for s in scenes.values()]
    if scene == "sliding":
        assert kinds == ["sliding"] * len(patches)
    else:
        assert sorted(k for k in kinds if k != "idle") == ["held", "held", "sliding", "sliding"]
    for name, s in scenes.items():
        ind, t = s.at(10.0)
        if s.kind == "idle":
            assert ind is None
            continue
        xy = layout.patch(name).taxel_xy()
        for when in np.linspace(0.6, 3.4, 8):  # the press's centre stays on the skin
            force, centre = ind.at(s.at(when)[1] if s.kind == "held" else when)
            assert np.min(np.linalg.norm(xy - centre, axis=1)) < 0.006, (name, when)
        force, centre = ind.at(t)
        if s.kind == "held":
            assert force == pytest.approx(2.0)
            assert ind.at(s.at(20.0)[1])[1] == pytest.approx(centre)  # still
    with pytest.raises(ValueError, match="unknown scene 'hug'"):
        scene_indentations(patches, "hug")


def test_the_yaml_header_states_the_figures() -> None:
    head = ROBOT.read_text().splitlines()[0]
    layout = yaml.safe_load(ROBOT.read_text())
    assert f"{len(layout['patches'])}" in head
