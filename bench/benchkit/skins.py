"""Skins for the ROS benches: layouts of many hexagon patches and their CAN frames.

Each patch is a copy of the default hexagon (6 roboskin12 triangles) on CAN addresses of its
own; frames come from the skin simulator (tactile_contact.sim) and are computed before any
timing, so that a load generator costs only the sending.
"""

from __future__ import annotations

import copy
from pathlib import Path

import can
import yaml

from benchkit import LAYOUT

#: The skin's period [ms] (50 Hz).
PERIOD_MS = 20


def multi_patch_layout(n: int, folder: Path, buses: int = 1) -> Path:
    """A layout of ``n`` hexagon patches on distinct CAN addresses (names patch<k>, frames
    skin_patch<k>), written to ``folder``/layout_<n>.yaml; with ``buses`` > 1 the patches in
    that many consecutive runs on buses bus0, bus1, … (``folder``/layout_<n>_<buses>buses.yaml)."""
    doc = yaml.safe_load(LAYOUT.read_text())
    base = doc["patches"][0]
    patches = []
    for k in range(n):
        p = copy.deepcopy(base)
        p["name"] = f"patch{k:02d}"
        p["frame_id"] = f"skin_patch{k:02d}"
        if buses > 1:
            p["bus"] = f"bus{k * buses // n}"
        for j, m in enumerate(p["modules"]):
            m["board"] = k // 2
            m["triangle"] = (k % 2) * 6 + j
        patches.append(p)
    doc["patches"] = patches
    path = folder / (f"layout_{n}.yaml" if buses == 1 else f"layout_{n}_{buses}buses.yaml")
    path.write_text(yaml.safe_dump(doc))
    return path


def patch_frames(
    layout: Path, n: int, seconds: float, pressed: int = 1, stagger: float = 0.0
) -> list[list[list[can.Message]]]:
    """Module frames ([period][patch] → frames) of the first ``n`` patches over ``seconds``:
    1 s unloaded (the driver calibrates), then the first ``pressed`` patches each pressed by
    its own 12 mm sphere at 2 N sliding in a 4 s sweep, repeated (patch k's sweep ``stagger``·k
    seconds ahead), the others idle (noise only). Timestamps are the simulation's: a sender
    stamps each frame when it sends it."""
    from tactile_contact.model.indenters import HertzSphere
    from tactile_contact.model.layout import load_layout
    from tactile_contact.sim.scenes import scenario_indentation
    from tactile_contact.sim.simulator import simulator_for_patch

    count = int(seconds / (PERIOD_MS * 1e-3))
    per_patch = []
    for k, patch in enumerate(load_layout(layout).patches[:n]):
        sim = simulator_for_patch(
            patch, fine_cell=5e-4, realtime=True, period_s=PERIOD_MS * 1e-3, noise_cdc=0.6, seed=k
        )
        ind = scenario_indentation("sweep", patch, HertzSphere(6e-3), 2.0, 4.0)
        rows = []
        for j in range(count):
            t = j * PERIOD_MS * 1e-3
            if k >= pressed or t < 1.0:
                rows.append(sim.period(None, t).messages)
            else:
                rows.append(sim.period(ind, (t - 1.0 + stagger * k) % 4.0).messages)
        per_patch.append(rows)
    return [[p[j] for p in per_patch] for j in range(count)]
