"""Whole-skin scenes: what presses each patch of a layout, for the simulator (issue 25).

- ``sliding`` (the worst case): every patch pressed by its own 12 mm sphere sliding 12–20 mm
  over its middle (2 N, a 4 s cycle: 0.5 s ramp, slide, 0.5 s release, 0.5 s rest), the
  patches' cycles staggered so that they are not all in the same phase;
- ``typical``: four patches in contact — two sliding as above, two held still (the same
  sphere pressed on the taxel nearest the patch centre and left there, the force constant) —
  and every other patch idle (noise only): a hand on an arm, a leg resting on a table;
- ``held``: every patch pressed and held still; ``idle``: nothing touches the skin (the cost of
  each kind of patch-frame alone).

:func:`scene_indentations` gives, per patch, the :class:`~tactile_contact.sim.simulator.
Indentation` (None: idle) and the time offset of its cycle (:func:`scenario_indentation`:
one patch's press, sweep or nothing, as skin_simulator plays it); the simulator
(:func:`~tactile_contact.sim.simulator.simulator_for_patch`) turns them into frames.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from tactile_contact.model.indenters import HertzSphere
from tactile_contact.model.layout import PatchLayout
from tactile_contact.sim.simulator import Indentation

SCENES = ("sliding", "typical", "held", "idle")
#: Force [N], sphere radius [m] and cycle [s] of every press.
FORCE_N, SPHERE_RADIUS_M, CYCLE_S = 2.0, 6e-3, 4.0
#: The stagger of the patches' cycles [s per patch index].
STAGGER_S = 0.17


def scenario_indentation(
    scenario: str, patch: PatchLayout, indenter: Any, force_n: float, cycle_s: float
) -> Indentation | None:
    """The scripted indentation of one cycle [s from cycle start]; None for ``idle``."""
    if scenario == "idle":
        return None
    xy = patch.taxel_xy()
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    # On the taxel nearest the patch centre: between taxels a small indenter may touch none.
    nearest = xy[np.argmin(np.linalg.norm(xy - (lo + hi) / 2, axis=1))]
    center = (float(nearest[0]), float(nearest[1]))
    hold = cycle_s - 1.5  # ramp 0.5 s, hold, release 0.5 s, rest 0.5 s
    if scenario == "press":
        return Indentation.press(indenter, force_n, center, start_s=0.0, ramp_s=0.5, hold_s=hold)
    if scenario == "sweep":
        margin = 0.15 * (hi[0] - lo[0])
        start = (float(lo[0] + margin), center[1])
        end = (float(hi[0] - margin), center[1])
        return Indentation.press(
            indenter, force_n, start, start_s=0.0, ramp_s=0.5, hold_s=hold, end=end
        )
    raise ValueError(f"scenario must be sweep, press or idle, got {scenario!r}")


def local_sweep(patch: PatchLayout, indenter: Any) -> Indentation:
    """A slide that stays on the skin: from the taxel nearest the patch's centre to the
    taxel 12–20 mm from it most nearly along +x (a large patch, or one made of separate
    pieces, such as an unrolled forearm, has gaps a straight sweep across it would cross)."""
    xy = patch.taxel_xy()
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    a = xy[np.argmin(np.linalg.norm(xy - (lo + hi) / 2, axis=1))]
    d = xy - a
    r = np.linalg.norm(d, axis=1)
    ring = (r >= 0.012) & (r <= 0.020)
    if not ring.any():
        ring = r > 0
    b = xy[ring][np.argmax(d[ring, 0] / r[ring])]
    hold = CYCLE_S - 1.5  # ramp 0.5 s, slide, release 0.5 s, rest 0.5 s
    return Indentation.press(
        indenter,
        FORCE_N,
        (float(a[0]), float(a[1])),
        start_s=0.0,
        ramp_s=0.5,
        hold_s=hold,
        end=(float(b[0]), float(b[1])),
    )


@dataclass(frozen=True)
class PatchScene:
    """What presses one patch: ``indentation`` (None: nothing) at cycle time
    ``(t + offset_s) % cycle_s``; ``kind`` is "sliding", "held" or "idle"."""

    kind: str
    indentation: Indentation | None
    offset_s: float = 0.0
    cycle_s: float = CYCLE_S

    def at(self, t: float) -> tuple[Indentation | None, float]:
        """(indentation, its time) for simulation time ``t`` [s]."""
        if self.indentation is None:
            return None, 0.0
        if self.kind == "held":
            return self.indentation, t  # (constant after its ramp)
        return self.indentation, (t + self.offset_s) % self.cycle_s


def typical_patches(names: list[str]) -> tuple[list[str], list[str]]:
    """The ``typical`` scene's (sliding, held) patches: four spread over the skin, taken at
    equal steps through the patch list (so on different parts of a whole-robot layout)."""
    if len(names) < 4:
        raise ValueError(f"the typical scene needs 4 patches, the layout has {len(names)}")
    step = len(names) / 4
    chosen = [names[int(k * step)] for k in range(4)]
    return chosen[:2], chosen[2:]


def scene_indentations(patches: list[Any], scene: str) -> dict[str, PatchScene]:
    """Patch name → what presses it in ``scene`` (one of :data:`SCENES`).

    Raises:
        ValueError: an unknown scene, or too few patches for it.
    """
    if scene not in SCENES:
        raise ValueError(f"unknown scene {scene!r} (known: {', '.join(SCENES)})")
    sphere = HertzSphere(SPHERE_RADIUS_M)
    names = [p.name for p in patches]
    if scene in ("sliding", "held", "idle"):
        sliding = names if scene == "sliding" else []
        held = names if scene == "held" else []
    else:
        sliding, held = typical_patches(names)
    out = {}
    for k, p in enumerate(patches):
        if p.name in sliding:
            out[p.name] = PatchScene("sliding", local_sweep(p, sphere), STAGGER_S * k)
        elif p.name in held:
            ind = scenario_indentation("press", p, sphere, FORCE_N, 1e9)  # held "forever"
            out[p.name] = PatchScene("held", ind)
        else:
            out[p.name] = PatchScene("idle", None)
    return out
