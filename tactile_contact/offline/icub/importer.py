"""iCub skin part (skinGui .ini + positions .txt [+ robot skin spec]) → a layout YAML.

:func:`import_part` reads the files (:mod:`.ini`, :mod:`.positions`, :mod:`.robot_xml`),
matches slots, CAN addresses and rows (:mod:`.slots`), chooses the patches, places the modules
of each in its flattened frame (:mod:`.placement`), and returns the layout (plain data and the
YAML text, validated by :func:`tactile_contact.model.layout.parse_layout`) with the report.

Patches (``split``): ``part`` makes one patch of the whole part, ``board`` one per CAN board,
``auto`` (default) the whole part when its taxel rows lie within AUTO_SURFACE_RMS of one fitted
cylinder or plane, its neighbour distances meet the targets (median ≤ 1.5 mm, 95th
percentile ≤ 4 mm) and it has at most AUTO_MAX_TAXELS taxels, else one per board. One patch
per part keeps contacts that straddle two boards whole; a part that is not one cylinder (the
torso, the upper arm) or is large (the legs) is split. Triangles
with different shift, CDC offset or noLoad never share a patch (one sensor section each).
"""

from __future__ import annotations

import copy
import hashlib
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from tactile_contact.model.layout import Layout, parse_layout
from tactile_contact.model.surface import Surface, matrix_quaternion
from tactile_contact.offline.icub.errors import IcubFileError
from tactile_contact.offline.icub.ini import read_ini
from tactile_contact.offline.icub.placement import PlacedPatch, module_placements, place_patch
from tactile_contact.offline.icub.positions import PositionsFile, read_positions
from tactile_contact.offline.icub.report import ImportReport
from tactile_contact.offline.icub.robot_xml import part_addresses, read_skin_spec
from tactile_contact.offline.icub.slots import Item, gather
from tactile_contact.offline.icub.surface_fit import SurfaceFit

SPLITS = ("auto", "part", "board")
#: ``auto`` keeps a part whole when its rows lie this close (rms) [m] to one fitted surface
#: and it has at most AUTO_MAX_TAXELS taxels (a 240-taxel forearm builds in ≈ 20 s of CPU; the
#: 380-taxel lower leg as one patch in ≈ 40 s and its deflection operator grows as cells²).
AUTO_SURFACE_RMS = 3.0e-3
AUTO_MAX_TAXELS = 300

#: What every imported patch gets besides its modules (the iCub V2 skin: 2 mm Ecoflex-like
#: layer, 2 mm electrodes; docs/layout.md). The deflection grid is as coarse as the traction
#: grid: a large patch's 1 mm deflection operator would be tens of megabytes.
PATCH_DEFAULTS: dict[str, Any] = {
    "elastomer": {"thickness": 0.002, "young": 210000.0, "poisson": 0.5},
    "grid": {
        "traction_cell": 0.002,
        "deflection_cell": 0.002,
        "margin": 0.003,
        "mask": "modules",
        "mask_distance": 0.003,
    },
    "model": {"kind": "love", "taxel_average": True},
    "solver": {
        "method": "nnls_tikhonov",
        "regulariser": "identity",
        "tikhonov": 0.1,
        "noise": 6.0e-6,
        "refine": "round",
        "max_contacts": 3,
    },
}


@dataclass
class ImportResult:
    """The outcome of :func:`import_part`.

    Attributes:
        layout: the validated layout.
        text: the layout YAML as written by the command (comments say where each module's
            placement came from).
        report: what was found and done.
        patches: the placed patches (their fitted surfaces and figures).
    """

    layout: Layout
    text: str
    report: ImportReport
    patches: list[PlacedPatch]


def _name(text: str) -> str:
    """A patch name stem from ``text``: what a ROS topic name takes (layout.PATCH_NAME)."""
    name = re.sub(r"[^A-Za-z0-9_]", "_", text)
    return name if name[:1].isascii() and name[:1].isalpha() else f"skin_{name}".rstrip("_")


def _sha256(path: str) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _surface(link: str, fit: SurfaceFit, centre_uv: np.ndarray) -> Surface:
    """The patch surface whose origin is the flattened point ``centre_uv``."""
    p0 = fit.unflatten(centre_uv[None, :])[0]
    if fit.shape == "plane":
        rot = np.column_stack([fit.ref, fit.axis, fit.normal])
        radius = None
    else:
        n = fit.normals(p0[None, :])[0]
        rot = np.column_stack([np.cross(fit.axis, n), fit.axis, n])
        radius = round(fit.radius, 6)
    q = matrix_quaternion(rot)
    return Surface(
        link,
        fit.shape,
        tuple(round(float(v), 6) for v in p0),  # type: ignore[arg-type]
        tuple(round(float(v), 8) for v in q / np.linalg.norm(q)),  # type: ignore[arg-type]
        radius,
    )


def _patch_groups(items: list[Item], report: ImportReport) -> list[list[Item]]:
    """Items split so that shift, CDC offset and noLoad are one per group."""
    groups: dict[tuple, list[Item]] = {}
    for it in items:
        keys = set(zip(it.shift, it.cdc_offset, it.no_load, strict=True))
        if len(keys) > 1:
            raise ValueError(
                f"slots {it.slots} ({it.sensor.type} of line {it.sensor.line}) have different "
                "shift, cdcOffset or noLoad in the skin spec, but form one sensor"
            )
        groups.setdefault(next(iter(keys)), []).append(it)
    if len(groups) > 1:
        report.notes.append(
            "the skin spec gives the modules different (shift, cdcOffset, noLoad): "
            + "; ".join(f"{k}: slots {[i.slots[0] for i in g]}" for k, g in groups.items())
            + "; one set of patches each"
        )
    return list(groups.values())


def _place(
    name: str, items: list[Item], pos: PositionsFile, report: ImportReport
) -> tuple[PlacedPatch, ImportReport]:
    """Place a copy of ``items`` with a report of its own (a candidate may be discarded)."""
    own = ImportReport()
    return place_patch(name, copy.deepcopy(items), pos, own), own


def _choose_patches(
    base: str, items: list[Item], pos: PositionsFile, split: str, report: ImportReport
) -> list[tuple[PlacedPatch, ImportReport]]:
    chosen: list[tuple[PlacedPatch, ImportReport]] = []
    groups = _patch_groups(items, report)
    for gi, group in enumerate(groups):
        stem = base if len(groups) == 1 else f"{base}_{gi}"
        whole = None
        multi = len({it.board_index for it in group}) > 1
        if split in ("auto", "part"):
            try:
                whole = _place(stem, group, pos, report)
            except IcubFileError as exc:
                if split == "part" or not multi:
                    raise
                # e.g. estimated (noisy) rows placed from each board's .ini drawing, whose
                # blocks then collide on one surface; boards placed alone do not meet
                report.notes.append(
                    f"{stem}: the part cannot be placed as one patch ({exc.problem}): one "
                    "patch per board"
                )
                whole = None
        if whole is not None:
            p = whole[0]
            ok = p.figures.within_targets and p.fit.rms <= AUTO_SURFACE_RMS
            small = p.figures.taxels <= AUTO_MAX_TAXELS
            if split == "part" or (ok and small) or not multi:
                chosen.append(whole)
                continue
            if not ok:
                why = (
                    f"one surface does not describe the whole part (rows off a {p.fit.shape} "
                    f"by {p.fit.rms * 1e3:.1f} mm rms, neighbour distances median "
                    f"{p.figures.median * 1e3:.2f} / p95 {p.figures.p95 * 1e3:.2f} mm)"
                )
            else:
                why = (
                    f"{p.figures.taxels} taxels are more than {AUTO_MAX_TAXELS} for one patch "
                    "(build time and memory grow with taxels × cells; a contact across a "
                    "board seam is then seen in part by each patch; --split part keeps one)"
                )
            report.notes.append(f"{stem}: {why}: one patch per board")
        for b in sorted({it.board_index for it in group}):
            sub = [it for it in group if it.board_index == b]
            chosen.append(_place(f"{stem}_b{sub[0].addresses[0]}", sub, pos, report))
    return chosen


def _module_line(t: str, board: int, tri: int, xy: np.ndarray, rot: float) -> str:
    return (
        f"{{type: {t}, board: {board}, triangle: {tri}, "
        f"position: [{xy[0]:.6f}, {xy[1]:.6f}], rotation_deg: {rot:.2f}}}"
    )


def _flow(d: dict[str, Any]) -> str:
    return yaml.safe_dump(d, default_flow_style=True, sort_keys=False, width=10_000).strip()


def _scalar(v: object) -> str:
    """``v`` as a YAML scalar that reads back as itself (``'1'``, ``'yes'`` quoted)."""
    return _flow([v])[1:-1]  # type: ignore[list-item]


def import_part(
    ini_path: str | Path,
    positions_path: str | Path,
    *,
    boards: tuple[int, ...] | None = None,
    skin_spec: str | Path | None = None,
    robot_skin: str | Path | None = None,
    wrapper: str | Path | None = None,
    port: str | None = None,
    link: str | None = None,
    name: str | None = None,
    bus: str = "",
    split: str = "auto",
    command: str = "",
) -> ImportResult:
    """Import one iCub skin part (see the module docstring).

    Args:
        ini_path, positions_path: the skinGui .ini and the positions .txt of the part.
        boards: CAN address of each board index (slot // 16), in slot order.
        skin_spec: the robot's ``*-skinSpec.xml``: enabled triangles, shift, cdcOffset, noLoad.
        robot_skin, wrapper: the robot's ``*-skin.xml`` and ``*-skin_wrapper.xml``: the board
            addresses of the wrapper port ``port`` (default: the .ini's robotPart).
        link: the robot link frame of the positions (default: the positions file's ``name``).
        name: patch name stem (default: the .ini's robotPart).
        bus: the CAN bus of the part's patches (the layout's ``bus``; "" leaves it out).
        split: ``auto``, ``part`` or ``board``.
        command: the command line, recorded in the YAML's header.

    Raises:
        IcubFileError: a file is unreadable or inconsistent (file and line named).
        ValueError: the files are consistent but cannot be imported as asked.
    """
    if bus and not re.fullmatch(r"[A-Za-z0-9_-]+", bus):
        raise ValueError(f"bus: expected a name of letters, digits, '_' or '-', got {bus!r}")
    if split not in SPLITS:
        raise ValueError(f"split must be one of {', '.join(SPLITS)}, got {split!r}")
    report = ImportReport()
    ini = read_ini(ini_path)
    pos = read_positions(positions_path)
    report.sources += [str(ini_path), str(positions_path)]
    spec = None
    if skin_spec is not None:
        spec = read_skin_spec(skin_spec)
        report.sources.append(str(skin_spec))
    boards_source = "--boards"
    if (robot_skin is None) != (wrapper is None):
        raise ValueError("give both the robot's skin.xml and its skin_wrapper.xml, or neither")
    if robot_skin is not None and wrapper is not None:
        if boards is not None:
            raise ValueError(
                "give the board addresses either with --boards or from the robot's files"
            )
        want = port or ini.robot_part
        if not want:
            raise ValueError(f"{ini.path} has no robotPart line: name the wrapper port (--port)")
        boards = part_addresses(robot_skin, wrapper, want)
        boards_source = f"{robot_skin} + {wrapper}, port {want}"
        report.sources += [str(robot_skin), str(wrapper)]
    frame = link or pos.link
    if not frame:
        raise IcubFileError(pos.path, None, "no 'name' line naming the link frame: give --link")
    base = _name(name or ini.robot_part or Path(ini_path).stem)

    items = gather(ini, pos, boards, boards_source, spec, report)
    placed = _choose_patches(base, items, pos, split, report)

    patches: list[dict[str, Any]] = []
    blocks: list[str] = []
    for patch, own in placed:
        report.anomalies += own.anomalies
        report.notes += own.notes
        report.patches.append(patch.figures)
        report.modules += module_placements(patch)
        surface = _surface(frame, patch.fit, patch.centre_uv)
        first = patch.items[0].item
        sensor: dict[str, Any] = {
            "epsilon_r": 4.37,
            "taxel_radius": 0.002,
            "farad_per_count": 3.2e-16,
            "no_load": first.no_load[0] if first.no_load[0] is not None else 240,
            "shift": first.shift[0] if first.shift[0] is not None else 2,
        }
        if first.cdc_offset[0] is not None:
            sensor["cdc_offset"] = first.cdc_offset[0]
        mods, lines = [], []
        rows = sorted(patch.modules(), key=lambda m: m[0].slots[m[1]])
        for it, k, t, xy, rot in rows:
            src = next(p for p in patch.items if p.item is it)
            mods.append(
                {
                    "type": t.name,
                    "board": it.addresses[k],
                    "triangle": it.triangles[k],
                    "position": [round(float(xy[0]), 6), round(float(xy[1]), 6)],
                    "rotation_deg": round(rot, 2),
                }
            )
            lines.append(
                f"      - {_module_line(t.name, it.addresses[k], it.triangles[k], xy, rot)}"
                f"  # slot {it.slots[k]}: position {src.position_source}, rotation "
                f"{src.rotation_source}"
            )
        d = {
            "name": patch.name,
            "frame_id": f"{patch.name}_skin",
            **({"bus": bus} if bus else {}),
            "surface": surface.to_dict(),
            "modules": mods,
            "elastomer": PATCH_DEFAULTS["elastomer"],
            "sensor": sensor,
            **{k: PATCH_DEFAULTS[k] for k in ("grid", "model", "solver")},
        }
        patches.append(d)
        f = patch.figures
        shape = f"cylinder of radius {f.radius * 1e3:.1f} mm" if f.radius else "plane"
        block = [
            f"  # {patch.name}: {f.modules} modules, {f.taxels} taxels on a {shape}; neighbouring "
            f"taxels' in-plane vs 3-D distance: median {f.median * 1e3:.2f}, "
            f"p95 {f.p95 * 1e3:.2f}, worst {f.worst * 1e3:.2f} mm",
            f"  - name: {_scalar(d['name'])}",
            f"    frame_id: {_scalar(d['frame_id'])}",
            *([f"    bus: {_scalar(bus)}"] if bus else []),
            f"    surface: {_flow(d['surface'])}",
            "    modules:",
            *lines,
        ]
        for key in ("elastomer", "sensor", "grid", "model", "solver"):
            block.append(f"    {key}: {_flow(d[key])}")
        blocks.append("\n".join(block))

    header = [
        "# iCub skin layout written by tactile-contact-import-icub (docs/icub.md).",
        *(f"# from {s} (sha256 {_sha256(s)[:16]})" for s in report.sources),
        *([f"# command: {command}"] if command else []),
        f"# {len(report.anomalies)} anomalies absorbed (see the command's report); the patch "
        "frame is the skin unrolled at the taxel layer, `surface` puts it on the robot.",
        "schema_version: 1",
        "patches:",
    ]
    text = "\n".join(header) + "\n" + "\n".join(blocks) + "\n"
    data = yaml.safe_load(text)
    if data["patches"] != patches:  # the hand-written YAML must say what was computed
        raise AssertionError("internal error: the YAML text does not match the layout")
    layout = parse_layout(data, str(ini_path))
    return ImportResult(layout, text, report, [p for p, _ in placed])
