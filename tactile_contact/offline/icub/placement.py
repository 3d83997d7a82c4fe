"""Placing a patch's modules in its flattened frame, and measuring what the flattening costs.

For one patch (a set of .ini sensors with their 3-D rows, :mod:`.slots`):

1. fit a plane or cylinder to the trusted taxel rows and flatten every row (:mod:`.surface_fit`);
2. swap back the rows of modules that carry a mirrored pattern, and for a plane choose the side
   seen from outside (:mod:`.handedness`); per module with three or more trusted,
   non-collinear taxel rows, fit the module template (rotation and translation) to them. Rows
   that fit badly (estimated positions) and modules that would overlap are left to the .ini;
3. per board, fit the .ini's drawing (X, Y) to the module origins (a similarity, reflection
   allowed). A module whose 3-D position is far from where its board's drawing puts it is an
   outlier in the file; it and modules without rows are placed from the .ini through that fit,
   and modules with fewer than three trusted rows take their rotation from it;
4. measure, over neighbouring taxels (3-D distance ≤ NEIGHBOUR_DISTANCE), the difference
   between the in-plane distance of the placed templates and the 3-D distance of the rows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from tactile_contact.model.modules import ModuleType, place_channels
from tactile_contact.offline.icub.errors import IcubFileError
from tactile_contact.offline.icub.handedness import (
    MIN_SPREAD,
    choose_side,
    rows_text,
    spread,
    unmirror,
)
from tactile_contact.offline.icub.positions import PositionsFile
from tactile_contact.offline.icub.report import ImportReport, ModulePlacement, PatchFigures
from tactile_contact.offline.icub.slots import Item
from tactile_contact.offline.icub.surface_fit import (
    RigidFit2D,
    SurfaceFit,
    fit_surface,
    rigid_fit_2d,
)

#: Taxels this close in 3-D [m] are neighbours for the distance check (about 1.5 pitches).
NEIGHBOUR_DISTANCE = 10.0e-3
#: A module whose 3-D position is farther than this [m] (and than OUTLIER_FACTOR × the board's
#: median) from where its board's .ini drawing puts it is an outlier of the positions file.
OUTLIER_DISTANCE = 8.0e-3
OUTLIER_FACTOR = 4.0
#: Rotations from the 3-D rows and the .ini that differ by more than this [deg] are reported.
ROTATION_MISMATCH_DEG = 10.0
#: A taxel row this far [m] from its place in the module placed by the other rows is reported.
TAXEL_OFFSET = 2.0e-3
#: A module whose rows fit its template worse than this (rms) [m] has rows too noisy to place
#: it (estimated positions, not CAD): its board's .ini drawing places it.
NOISY_RMS = 1.5e-3
#: Placed taxels of two modules closer than this [m] overlap (two 2 mm electrodes): the files
#: contradict each other there.
MIN_TAXEL_GAP = 4.0e-3


@dataclass
class PlacedItem:
    """An item's pose in the flattened patch frame (before centring).

    Attributes:
        item: the .ini sensor and its rows.
        offset: (2,) its template origin [m].
        angle_deg: its template rotation [deg] (never mirrored: see the module doc).
        position_source, rotation_source: ``3-D`` or ``.ini``.
        used: trusted taxel rows that placed it.
        fit_rms: rms [m] of those rows from the placed template (None: no fit).
        note: why the .ini was used.
    """

    item: Item
    offset: NDArray[np.float64]
    angle_deg: float
    position_source: str
    rotation_source: str
    used: int
    fit_rms: float | None
    note: str = ""


@dataclass
class PlacedPatch:
    """A placed patch: its items, the fitted surface and the frame's origin on it."""

    name: str
    items: list[PlacedItem]
    fit: SurfaceFit
    centre_uv: NDArray[np.float64]  # flattened point that becomes the patch frame's (0, 0)
    figures: PatchFigures

    def modules(self) -> list[tuple[Item, int, ModuleType, NDArray[np.float64], float]]:
        """(item, slot index within it, type, position [m], rotation [deg]) of each module,
        positions in the patch frame."""
        return [
            (p.item, k, t, p.offset - self.centre_uv, p.angle_deg % 360.0)
            for p in self.items
            for k, t in enumerate(p.item.types)
        ]


def _circular_median(angles: list[float]) -> float:
    """The angle [deg] among ``angles`` [rad] with the least summed distance to the others."""
    a = np.asarray(angles)
    d = np.abs(np.angle(np.exp(1j * (a[:, None] - a[None, :]))))
    return float(np.degrees(a[int(np.argmin(d.sum(axis=1)))]) % 360.0)


def _ini_xy(it: Item) -> NDArray[np.float64]:
    return np.array([it.sensor.x, it.sensor.y])


def place_patch(
    name: str, items: list[Item], pos: PositionsFile, report: ImportReport
) -> PlacedPatch:
    """Fit, flatten and place one patch's items (see the module doc); raises ValueError when
    a module can be placed neither from its rows nor from the .ini."""
    trusted = [it.xyz[it.trusted] for it in items]
    pts = np.concatenate(trusted) if trusted else np.zeros((0, 3))
    if len(pts) < 3:
        raise ValueError(f"patch {name}: fewer than 3 trusted taxel rows to fit a surface to")
    rows = np.concatenate([it.rows[it.trusted] for it in items])
    normals = pos.normals[rows]
    varied = np.ptp(normals, axis=0).max() > 0.05 and np.all(
        np.abs(np.linalg.norm(normals, axis=1) - 1) < 0.05
    )
    fit = fit_surface(pts, normals if varied else None)
    fit = choose_side(fit, items, pos, report, name)
    unmirror(items, fit, pos, report)

    measured = {id(it): it.trusted.copy() for it in items}  # own rows, for the figures
    own: dict[int, RigidFit2D] = {}  # items whose rows fix rotation and position
    origins: dict[int, NDArray] = {}  # flattened origin of items whose rows fix it
    force_ini: dict[int, str] = {}  # items to place from the .ini → why
    for it in items:
        uv = fit.flatten(it.xyz)
        t = np.flatnonzero(it.trusted)
        if len(t) >= 3 and spread(it.template[t]) >= MIN_SPREAD:
            f = rigid_fit_2d(it.template[t], uv[t], False)
            origins[id(it)] = f.offset
            own[id(it)] = f
            if f.rms > NOISY_RMS and it.gui.gui_units_per_mm is not None:
                force_ini[id(it)] = f"its rows fit the template to {f.rms * 1e3:.1f} mm rms only"
                report.add(
                    "noisy_rows",
                    f"{pos.path}: slot {it.slots[0]}: rows {rows_text(it, t)} fit the module's "
                    f"template to {f.rms * 1e3:.1f} mm rms (more than {NOISY_RMS * 1e3:g} mm: "
                    "estimated, not measured positions?); placed from its board's .ini drawing",
                    slot=it.slots[0],
                    rows=it.rows[t].tolist(),
                )
        elif it.origin_channel is not None and it.trusted[it.origin_channel]:
            origins[id(it)] = uv[it.origin_channel]

    by_board: dict[int, list[Item]] = {}
    for it in items:
        by_board.setdefault(it.board_index, []).append(it)
    drawing = _drawings(by_board, origins, force_ini, pos, report)
    said: set[int] = set()  # slots whose rotation mismatch is reported
    for _ in range(len(items) + 1):
        ordered = _place_items(items, fit, own, force_ini, drawing, by_board, report, said)
        clash = _overlap(ordered)
        if clash is None:
            break
        a, b, gap = clash
        movable = [x for x in (a, b) if id(x.item) not in force_ini and x.item.gui.gui_units_per_mm]
        if not movable or any(id(x.item) not in origins for x in movable):
            raise IcubFileError(
                a.item.sensor.path or "the .ini",
                a.item.sensor.line,
                f"slots {a.item.slots[0]} and {b.item.slots[0]} (.ini lines {a.item.sensor.line} "
                f"and {b.item.sensor.line}) overlap once placed (taxels {gap * 1e3:.1f} mm "
                f"apart; positions from {a.position_source} and {b.position_source}): "
                f"{pos.path} and the .ini disagree on where these modules are (the positions "
                "file of another part or revision?)",
            )
        for x in movable:
            force_ini[id(x.item)] = (
                f"its rows made it overlap slot {(b if x is a else a).item.slots[0]}"
            )
            report.add(
                "overlap",
                f"slots {a.item.slots[0]} and {b.item.slots[0]}: placed from their rows, their "
                f"taxels come {gap * 1e3:.1f} mm close (electrodes overlap); slot "
                f"{x.item.slots[0]} placed from its board's .ini drawing instead",
                slot=x.item.slots[0],
            )
    for it in items:
        it.trusted = measured[id(it)]
    _report_offsets(ordered, fit, pos, report)
    xy = np.concatenate(
        [
            place_channels(t, tuple(p.offset), p.angle_deg)[t.taxel_mask]
            for p in ordered
            for t in p.item.types
        ]
    )
    centre = np.round((xy.min(axis=0) + xy.max(axis=0)) / 2, 4)
    figures = _figures(name, ordered, fit)
    return PlacedPatch(name, ordered, fit, centre, figures)


def _drawings(
    by_board: dict[int, list[Item]],
    origins: dict[int, NDArray],
    force_ini: dict[int, str],
    pos: PositionsFile,
    report: ImportReport,
) -> dict[int, RigidFit2D]:
    """Per board: the .ini drawing → flattened origins (similarity, reflection allowed), with
    the file's outlier modules left out of the fit (and marked for .ini placement)."""
    drawing: dict[int, RigidFit2D] = {}
    for b, group in by_board.items():
        have = [it for it in group if id(it) in origins]
        while len(have) >= 2:
            src = np.array([_ini_xy(it) for it in have])
            dst = np.array([origins[id(it)] for it in have])
            fits = [rigid_fit_2d(src, dst, m, scale=True) for m in (False, True)]
            best = min(fits, key=lambda f: f.rms)
            res = np.linalg.norm(best.apply(src) - dst, axis=1)
            k = int(np.argmax(res))
            if len(have) >= 4 and res[k] > max(OUTLIER_DISTANCE, OUTLIER_FACTOR * np.median(res)):
                it = have.pop(k)
                force_ini[id(it)] = f"its rows put it {res[k] * 1e3:.1f} mm off its board's drawing"
                report.add(
                    "outlier_module",
                    f"{pos.path}: slot {it.slots[0]}: its rows put it {res[k] * 1e3:.1f} mm "
                    "from where its board's .ini drawing places it among the board's other "
                    "modules; placed from the .ini",
                    slot=it.slots[0],
                    rows=it.rows[it.has_row].tolist(),
                )
                continue
            drawing[b] = best
            break
        if b in drawing:
            mirrors = [it.sensor.mirror for it in group]
            if drawing[b].mirrored != (sum(mirrors) * 2 > len(mirrors)):
                report.add(
                    "mirror_flag",
                    f"board index {b} (address {group[0].addresses[0]}): the .ini draws it "
                    f"{'mirror-imaged' if drawing[b].mirrored else 'as it is'} relative to the "
                    f"3-D rows, but its Mirror column says {round(float(np.mean(mirrors)))}; "
                    "the 3-D rows decide",
                    slot=group[0].slots[0],
                )
    return drawing


def _place_items(
    items: list[Item],
    fit: SurfaceFit,
    own: dict[int, RigidFit2D],
    force_ini: dict[int, str],
    drawing: dict[int, RigidFit2D],
    by_board: dict[int, list[Item]],
    report: ImportReport,
    said: set[int],
) -> list[PlacedItem]:
    """Each item's pose: its own rows' fit, else the .ini (see the module doc)."""
    # The .ini's Orient column is exact up to one angle per board (its drawing's rotation):
    # that angle from the modules the rows turn (circular median), else from the drawing fit.
    board_angle: dict[int, float] = {}
    for b, d in drawing.items():
        s = -1.0 if d.mirrored else 1.0
        diffs = [
            math.radians(own[id(it)].angle_deg - s * it.sensor.orient_deg)
            for it in by_board[b]
            if id(it) in own and id(it) not in force_ini
        ]
        board_angle[b] = _circular_median(diffs) if diffs else d.angle_deg
    out: list[PlacedItem] = []
    for it in items:
        d = drawing.get(it.board_index)
        ini_angle = None
        if d is not None:
            th = -it.sensor.orient_deg if d.mirrored else it.sensor.orient_deg
            ini_angle = (board_angle[it.board_index] + th) % 360.0
        slot = it.slots[0]
        t = np.flatnonzero(it.trusted)
        if id(it) in own and id(it) not in force_ini:
            f = own[id(it)]
            out.append(PlacedItem(it, f.offset, f.angle_deg, "3-D", "3-D", len(t), f.rms))
            if ini_angle is not None and slot not in said:
                diff = abs((f.angle_deg - ini_angle + 180.0) % 360.0 - 180.0)
                if diff > ROTATION_MISMATCH_DEG:
                    said.add(slot)
                    report.add(
                        "rotation_mismatch",
                        f"slot {slot}: its rows turn it by {f.angle_deg:.1f} deg, the .ini "
                        f"(line {it.sensor.line}) by {ini_angle:.1f} deg; the rows decide",
                        slot=slot,
                    )
            continue
        why = force_ini.get(
            id(it), "no trusted rows" if not len(t) else "too few trusted rows to turn it"
        )
        from_ini = id(it) in force_ini or not len(t)
        if ini_angle is None or d is None or (from_ini and it.gui.gui_units_per_mm is None):
            raise IcubFileError(
                it.sensor.path or "the .ini",
                it.sensor.line,
                f"cannot place slot {slot} ({it.sensor.type}): "
                f"{why}, and its board has too few placed modules (or the type's drawing is "
                "not to scale) to place it from the .ini",
            )
        ang = math.radians(ini_angle)
        rot = np.array([[math.cos(ang), -math.sin(ang)], [math.sin(ang), math.cos(ang)]])
        if from_ini:
            offset = d.apply(_ini_xy(it))[0]
            out.append(PlacedItem(it, offset, ini_angle, ".ini", ".ini", 0, None, why))
        else:
            uv = fit.flatten(it.xyz[t])
            offset = np.mean(uv - it.template[t] @ rot.T, axis=0)
            rms = float(np.sqrt(np.mean(np.sum((it.template[t] @ rot.T + offset - uv) ** 2, 1))))
            out.append(PlacedItem(it, offset, ini_angle, "3-D", ".ini", len(t), rms, why))
    return out


def _report_offsets(
    placed: list[PlacedItem], fit: SurfaceFit, pos: PositionsFile, report: ImportReport
) -> None:
    """Taxel rows far from their placed module's template (a row the file has wrong)."""
    for p in placed:
        if p.position_source != "3-D":
            continue
        it = p.item
        xy = np.concatenate([place_channels(t, tuple(p.offset), p.angle_deg) for t in it.types])
        t = np.flatnonzero(it.trusted)
        res = np.linalg.norm(fit.flatten(it.xyz[t]) - xy[t], axis=1)
        for k in np.flatnonzero(res > max(TAXEL_OFFSET, 3.0 * float(np.median(res)))):
            ch = int(t[k])
            r = int(it.rows[ch])
            report.add(
                "taxel_offset",
                f"{pos.path}:{pos.line(r)}: slot {it.slots[ch // 12]} channel {ch % 12} (row "
                f"{r}) lies {res[k] * 1e3:.1f} mm from its place in the module placed by the "
                "other rows; the module type's geometry is kept",
                slot=it.slots[ch // 12],
                rows=[r],
            )


def _overlap(placed: list[PlacedItem]) -> tuple[PlacedItem, PlacedItem, float] | None:
    """The first two modules whose placed taxels come closer than MIN_TAXEL_GAP, if any."""
    xy, owner = [], []
    for k, p in enumerate(placed):
        for t in p.item.types:
            c = place_channels(t, tuple(p.offset), p.angle_deg)[t.taxel_mask]
            xy.append(c)
            owner += [k] * len(c)
    pts, who = np.concatenate(xy), np.asarray(owner)
    for i, j in sorted(cKDTree(pts).query_pairs(MIN_TAXEL_GAP)):
        if who[i] != who[j]:
            return placed[who[i]], placed[who[j]], float(np.linalg.norm(pts[i] - pts[j]))
    return None


def _figures(name: str, placed: list[PlacedItem], fit: SurfaceFit) -> PatchFigures:
    """The neighbour-distance check of a placed patch (see the module doc)."""
    plane, space = [], []
    n_taxels = 0
    for p in placed:
        it = p.item
        xy = np.concatenate([place_channels(t, tuple(p.offset), p.angle_deg) for t in it.types])
        n_taxels += int(it.taxel.sum())
        plane.append(xy[it.trusted])
        space.append(it.xyz[it.trusted])
    a, b = np.concatenate(plane), np.concatenate(space)
    pairs = np.array(sorted(cKDTree(b).query_pairs(NEIGHBOUR_DISTANCE)), dtype=np.int64)
    if len(pairs) == 0:
        diff = np.zeros(0)
    else:
        d2 = np.linalg.norm(a[pairs[:, 0]] - a[pairs[:, 1]], axis=1)
        d3 = np.linalg.norm(b[pairs[:, 0]] - b[pairs[:, 1]], axis=1)
        diff = np.abs(d2 - d3)
    return PatchFigures(
        name=name,
        shape=fit.shape,
        radius=fit.radius if fit.shape == "cylinder" else None,
        surface_rms=fit.rms,
        surface_worst=fit.worst,
        modules=sum(len(p.item.types) for p in placed),
        taxels=n_taxels,
        pairs=len(diff),
        median=float(np.median(diff)) if len(diff) else math.nan,
        p95=float(np.percentile(diff, 95)) if len(diff) else math.nan,
        worst=float(diff.max()) if len(diff) else math.nan,
    )


def module_placements(patch: PlacedPatch) -> list[ModulePlacement]:
    """The report's per-module lines of a placed patch."""
    return [
        ModulePlacement(
            slot=p.item.slots[k],
            board=p.item.addresses[k],
            triangle=p.item.triangles[k],
            type=t.name,
            patch=patch.name,
            position_source=p.position_source,
            rotation_source=p.rotation_source,
            taxels_3d=p.used,
            fit_rms=p.fit_rms,
            note=p.note,
        )
        for p in patch.items
        for k, t in enumerate(p.item.types)
    ]
