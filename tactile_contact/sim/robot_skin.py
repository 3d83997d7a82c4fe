"""A whole iCub-like robot's skin as one layout, for simulation and load benchmarks.

``config/icub_robot.yaml`` is made by :func:`icub_robot` (``python -m
tactile_contact.sim.robot_skin``) from:

- the iCub parts imported from the robot's own files (config/icub/, tactile-contact-import-icub,
  docs/icub.md): the left forearm (V2, 24 modules), the left hand's palm and the left lower
  leg (38 modules, one patch per board); the right side is a copy of them (names and frames
  ``right_…``, on buses of its own; no ``surface``: the right part's pose on the body is not
  the mirrored left one's, and none is claimed);
- iCub-like synthetic parts where no imported part exists yet, with the module counts of the
  real robot (issue 25): upper arms (40 modules), upper legs (68) and the torso (44), as
  strips of iCub V2 triangles (10 taxels and 2 thermal pads each, side 33 mm) two rows high,
  one patch per CAN board (at most 16 triangles).

34 patches, 3928 taxels on 7 buses: each arm on one (68 modules), each leg on two (upper 68,
lower 38), the torso on one (44). A 1 Mbit/s bus carries ≈ 8000 frames/s, i.e. ≈ 80 modules
at 50 Hz (two 8-byte frames each, ≈ 125 µs a frame): the 68-module buses run at ≈ 85 %.
"""

from __future__ import annotations

import argparse
import copy
import math
import sys
from pathlib import Path
from typing import Any

import yaml

from tactile_contact.model.layout import parse_layout

CONFIG = Path(__file__).resolve().parents[2] / "config"
#: Edge of an iCub V2 triangle [m]: neighbouring up and down triangles are half of it apart.
V2_SIDE = 0.033
_V2 = {
    "elastomer": {"thickness": 0.002, "young": 2.1e5, "poisson": 0.5},
    "sensor": {
        "epsilon_r": 4.37,
        "taxel_radius": 0.002,
        "farad_per_count": 0.32e-15,
        "no_load": 240,
        "shift": 2,
    },
    "grid": {
        "traction_cell": 0.002,
        "deflection_cell": 0.002,
        "margin": 0.003,
        "mask": "modules",
        "mask_distance": 0.003,
    },
}
#: Synthetic parts: name → modules per board (one patch each), boards from the first number.
SYNTHETIC = {
    "upper_arm": ((8, 10), (9, 10), (10, 10), (11, 10)),
    "upper_leg": ((0, 14), (1, 14), (2, 14), (3, 13), (4, 13)),
    "torso": ((0, 11), (1, 11), (2, 11), (3, 11)),
}
#: Imported parts (config/icub) per side, with the bus they go on.
IMPORTED = (("left_forearm_V2.yaml", "arm"), ("left_hand_V2_1.yaml", "arm"))
IMPORTED_LEG = ("left_leg_lower.yaml", "leg_lower")


def triangle_strip(n: int, board: int) -> list[dict[str, Any]]:
    """``n`` iCub V2 triangles (triangle addresses 0…n−1 on ``board``) tiled in two rows:
    column i of row r points up when i + r is even; up and down neighbours are half a side
    apart along x, rows a triangle's height apart. Positions are each triangle's centroid."""
    height = V2_SIDE * math.sqrt(3.0) / 2.0
    per_row = math.ceil(n / 2)
    modules = []
    for k in range(n):
        r, i = divmod(k, per_row)
        up = (i + r) % 2 == 0
        y = r * height + (0.0 if up else height / 3.0)
        modules.append(
            {
                "type": "icub_v2_10pad",
                "board": board,
                "triangle": k,
                "position": [round(i * V2_SIDE / 2.0, 6), round(y, 6)],
                "rotation_deg": 0.0 if up else 180.0,
            }
        )
    return modules


def synthetic_part(part: str, side: str, bus: str) -> list[dict[str, Any]]:
    """The patches (one per board) of a synthetic part; ``side`` "" for the torso."""
    prefix = f"{side}_{part}" if side else part
    patches = []
    for board, n in SYNTHETIC[part]:
        name = f"{prefix}_b{board}"
        patches.append(
            {
                "name": name,
                "frame_id": f"{name}_skin",
                "bus": bus,
                "modules": triangle_strip(n, board),
                **copy.deepcopy(_V2),
            }
        )
    return patches


def imported_part(path: Path, side: str, bus: str) -> list[dict[str, Any]]:
    """The patches of an imported left part, for ``side`` (right: renamed, no surface)."""
    patches = yaml.safe_load(path.read_text())["patches"]
    for p in patches:
        p["bus"] = bus
        if side == "right":
            p["name"] = p["name"].replace("left", "right", 1)
            p["frame_id"] = p.get("frame_id", p["name"]).replace("left", "right", 1)
            p.pop("surface", None)
    return patches


def icub_robot(config: Path = CONFIG) -> dict[str, Any]:
    """The whole robot's layout (plain data, as a layout YAML holds it)."""
    patches: list[dict[str, Any]] = []
    for side in ("left", "right"):
        arm = f"{side}_arm"
        for name, _ in IMPORTED:
            patches += imported_part(config / "icub" / name, side, arm)
        patches += synthetic_part("upper_arm", side, arm)
        patches += imported_part(config / "icub" / IMPORTED_LEG[0], side, f"{side}_leg_lower")
        patches += synthetic_part("upper_leg", side, f"{side}_leg_upper")
    patches += synthetic_part("torso", "", "torso")
    return {"schema_version": 1, "patches": patches}


HEADER = """\
# A whole iCub-like robot's skin for simulation and load benchmarks (issue 25): {patches}
# patches, {taxels} taxels on {buses} CAN buses. Made by `python -m tactile_contact.sim.robot_skin`
# (tactile_contact/sim/robot_skin.py says what is imported from config/icub/ and what is
# synthetic); do not edit by hand.
"""


def write(path: Path, config: Path = CONFIG) -> dict[str, Any]:
    """Write the layout to ``path`` (validated first); its figures."""
    doc = icub_robot(config)
    layout = parse_layout(doc, str(path))
    figures = {
        "patches": len(layout.patches),
        "taxels": sum(len(p.taxel_ids()) for p in layout.patches),
        "buses": len(layout.buses()),
    }
    path.write_text(HEADER.format(**figures) + yaml.safe_dump(doc, sort_keys=False, width=100))
    return figures


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("-o", "--out", type=Path, default=CONFIG / "icub_robot.yaml")
    args = ap.parse_args(argv)
    figures = write(args.out)
    print(
        f"{args.out}: {figures['patches']} patches, {figures['taxels']} taxels, "
        f"{figures['buses']} buses"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
