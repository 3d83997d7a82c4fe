"""Which way round a module's rows are: mirrored patterns, and the outside of a flat part.

The skin seen from outside is the module template as it is (CONVENTIONS.md §5, docs/icub.md):
a module whose rows only fit the template mirror-imaged carries a mirrored pattern in the
positions file (the forearm V2's board 13, written by a generator that ignored the .ini's
Mirror column). Its rows are swapped back channel by channel (k ↔ the channel at k's mirror
image) and the anomaly reported; modules with too few rows of their own to tell follow their
board's majority. For a plane the same test chooses which side is outside.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from tactile_contact.model.modules import ModuleType
from tactile_contact.offline.icub.positions import PositionsFile
from tactile_contact.offline.icub.report import ImportReport
from tactile_contact.offline.icub.slots import Item
from tactile_contact.offline.icub.surface_fit import (
    RigidFit2D,
    SurfaceFit,
    flip_plane,
    rigid_fit_2d,
)

#: A template fits mirrored (or unmirrored) when the other fit is this much worse ...
MIRROR_RATIO = 2.0
#: ... and at least this bad [m].
MIRROR_MIN = 1.5e-3
#: Rows spread less than this [m] across their main direction cannot fix a rotation.
MIN_SPREAD = 0.8e-3


def _mirror_permutation(types: list[ModuleType]) -> NDArray[np.int64] | None:
    """Channel k ↔ the channel at k's mirror image (x → −x) within the same module, for
    every taxel channel; None when a taxel has no mirror partner."""
    perm = []
    for s, t in enumerate(types):
        xy = t.channel_xy
        for k in range(len(xy)):
            d = np.hypot(xy[:, 0] + xy[k, 0], xy[:, 1] - xy[k, 1])
            m = int(np.argmin(d))
            if d[m] > 5e-5 or t.taxel[m] != t.taxel[k]:
                if t.taxel[k]:
                    return None
                m = k
            perm.append(12 * s + m)
    return np.asarray(perm, dtype=np.int64)


def spread(xy: NDArray[np.float64]) -> float:
    if len(xy) < 3:
        return 0.0
    s = np.linalg.svd(xy - xy.mean(axis=0), compute_uv=False)
    return float(s[-1] / math.sqrt(len(xy)))


def _handedness(item: Item, uv: NDArray[np.float64]) -> tuple[str, RigidFit2D, RigidFit2D] | None:
    t = np.flatnonzero(item.trusted)
    if len(t) < 3 or spread(item.template[t]) < MIN_SPREAD:
        return None
    proper = rigid_fit_2d(item.template[t], uv[t], False)
    mirror = rigid_fit_2d(item.template[t], uv[t], True)
    if mirror.rms * MIRROR_RATIO < proper.rms and proper.rms > MIRROR_MIN:
        return "mirrored", proper, mirror
    if proper.rms * MIRROR_RATIO < mirror.rms and mirror.rms > MIRROR_MIN:
        return "proper", proper, mirror
    return "undecided", proper, mirror


def rows_text(item: Item, idx: NDArray | list[int]) -> str:
    r = [int(item.rows[i]) for i in idx]
    return ", ".join(map(str, r[:6])) + (" ..." if len(r) > 6 else "")


def choose_side(
    fit: SurfaceFit, items: list[Item], pos: PositionsFile, report: ImportReport, name: str
) -> SurfaceFit:
    """For a plane: the side from which the modules read as unmirrored templates."""
    if fit.shape != "plane":
        return fit
    votes = {"proper": 0, "mirrored": 0}
    for it in items:
        h = _handedness(it, fit.flatten(it.xyz))
        if h is not None and h[0] in votes:
            votes[h[0]] += 1
    if votes["mirrored"] > votes["proper"]:
        fit = flip_plane(fit)
        votes = {"proper": votes["mirrored"], "mirrored": votes["proper"]}
    elif votes["proper"] == votes["mirrored"] == 0:
        rows = np.concatenate([it.rows[it.trusted] for it in items])
        n = pos.normals[rows]
        if len(n) and np.all(np.abs(n @ fit.normal) > 0.9) and float(np.mean(n @ fit.normal)) < 0:
            fit = flip_plane(fit)
        report.notes.append(
            f"{name}: no module decides which side of the plane is outside; "
            "taken from the file's normals where they are perpendicular to it"
        )
        return fit
    report.notes.append(
        f"{name}: flat; its outside is the side from which {votes['proper']} module(s) read "
        f"as the unmirrored template ({votes['mirrored']} mirrored)"
    )
    return fit


def unmirror(items: list[Item], fit: SurfaceFit, pos: PositionsFile, report: ImportReport) -> None:
    """Swap back the rows of modules whose file pattern is mirrored (see the module doc)."""
    verdicts = {id(it): _handedness(it, fit.flatten(it.xyz)) for it in items}
    boards: dict[int, list[str]] = {}
    for it in items:
        v = verdicts[id(it)]
        if v is not None and v[0] != "undecided":
            boards.setdefault(it.board_index, []).append(v[0])
    for it in items:
        v = verdicts[id(it)]
        said = boards.get(it.board_index, [])
        majority = said.count("mirrored") >= 2 and said.count("mirrored") > 2 * said.count("proper")
        if v is not None and v[0] == "mirrored":
            why = (
                f"its {int(it.trusted.sum())} own rows fit the template mirrored (rms "
                f"{v[2].rms * 1e3:.1f} mm) and not as it is (rms {v[1].rms * 1e3:.1f} mm)"
            )
        elif (v is None or v[0] == "undecided") and majority and it.has_row.any():
            why = (
                f"too few rows of its own to tell; {said.count('mirrored')} of its board's "
                f"{len(said)} modules that tell are mirrored"
            )
        else:
            continue
        perm = _mirror_permutation(it.types)
        if perm is None:
            it.trusted[:] = False
            report.add(
                "mirrored_pattern",
                f"{pos.path}: slot {it.slots[0]}: rows {rows_text(it, range(len(it.rows)))} "
                f"are a mirror image of the module ({why}); its type has no mirror "
                "partner for every taxel, so its rows are not used",
                slot=it.slots[0],
                rows=it.rows[it.has_row].tolist(),
            )
            continue
        it.xyz = it.xyz[perm]
        it.has_row = it.has_row[perm]
        it.trusted = it.trusted[perm] & it.taxel
        report.add(
            "mirrored_pattern",
            f"{pos.path}: slot {it.slots[0]}: rows {it.rows[0]}..{it.rows[-1]} carry the "
            f"mirror image of the physical pattern ({why}); the skin seen from outside is the "
            "unmirrored template (docs/icub.md), so the rows are read swapped back "
            "(channels 0<->7, 1<->5, 2<->4, 8<->11)",
            slot=it.slots[0],
            rows=it.rows[it.has_row].tolist(),
        )
