"""From a skinGui .ini and a positions file to the modules to place, with their 3-D rows.

This is the bookkeeping half of the import: which slot is which CAN board and triangle
(slot = 16·board index + triangle, board index → address), which rows of the positions file
belong to which module (row = 12·slot + channel), which of those rows can be trusted, and
everything in the files that does not add up. Geometry is :mod:`.placement`'s job.

Errors (IcubFileError, file and line): unknown sensor types, sensors overlapping in slots,
a row count that is not 192 rows per board, rows holding taxels of slots the .ini does not
list, a .ini whose modules have no rows at all, too few board addresses. Anomalies that can be
absorbed are recorded in the report with slot and rows: rows copied from the triangle centre
(or otherwise duplicated), empty taxel rows, taxel2Repr of the wrong length or with markers
that contradict the rows, a constant normals column, data in the last row (skinPart never
reads it), a stale cardid, triangles the skin spec disables.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from tactile_contact.model.modules import MODULE_TYPES, ModuleType
from tactile_contact.offline.icub.errors import IcubFileError
from tactile_contact.offline.icub.gui_types import SUPPORTED, UNSUPPORTED, GuiType, known_types
from tactile_contact.offline.icub.ini import IniSensor, SkinGuiIni
from tactile_contact.offline.icub.positions import PositionsFile
from tactile_contact.offline.icub.report import ImportReport
from tactile_contact.offline.icub.robot_xml import SkinSpec

ROWS_PER_SLOT = 12
ROWS_PER_BOARD = 192
#: Two rows closer than this [m] are the same position (the files print 0.1 µm … 0.1 mm).
SAME_POSITION = 1.0e-6
#: A taxel row farther than this [m] from the median of its module's rows is not the
#: module's (a ROBOSKIN triangle's taxels lie within ≈ 15 mm of its centre): a mistyped row
#: (one digit shifted put a board's rows 0.44 m off and mirrored all ten of its modules).
ROW_SPREAD_M = 0.04
#: The module type's channel that is its origin, when one is (icub_v2_10pad: the centre).
_ORIGIN_CHANNEL = {"icub_v2_10pad": 3}


@dataclass
class Item:
    """One .ini sensor to place: one module, or several sharing one pose (the palm).

    Channel arrays have 12 entries per slot, in slot order.

    Attributes:
        sensor: its .ini line.
        gui: its skinGui type.
        slots: the data slots it occupies (those the skin spec disables removed).
        types: module type per slot.
        addresses, triangles: CAN board address and triangle per slot.
        template: (12·n, 2) channel centres [m] in the sensor's own frame.
        taxel: (12·n,) the channel is a pressure taxel.
        rows: (12·n,) positions-file row of each channel.
        xyz: (12·n, 3) the rows' positions [m] (after any correction, e.g. un-mirroring).
        has_row: (12·n,) the row holds data.
        trusted: (12·n,) a taxel whose row is its own position (not empty, not a copy).
        shift, cdc_offset, no_load: per slot, from the skin spec (None without one).
    """

    sensor: IniSensor
    gui: GuiType
    slots: list[int]
    types: list[ModuleType]
    addresses: list[int]
    triangles: list[int]
    template: NDArray[np.float64]
    taxel: NDArray[np.bool_]
    rows: NDArray[np.int64]
    xyz: NDArray[np.float64]
    has_row: NDArray[np.bool_]
    trusted: NDArray[np.bool_]
    shift: list[int | None] = field(default_factory=list)
    cdc_offset: list[int | None] = field(default_factory=list)
    no_load: list[int | None] = field(default_factory=list)

    @property
    def board_index(self) -> int:
        return self.slots[0] // 16

    @property
    def origin_channel(self) -> int | None:
        """Channel at the template origin (its row is the module position), if one."""
        return _ORIGIN_CHANNEL.get(self.types[0].name) if len(self.types) == 1 else None

    def keep(self, mask: list[bool]) -> None:
        """Keep only the slots where ``mask`` is True."""
        ch = np.repeat(np.asarray(mask, dtype=bool), ROWS_PER_SLOT)
        for name in ("slots", "types", "addresses", "triangles", "shift", "cdc_offset",
                     "no_load"):  # fmt: skip
            setattr(self, name, [v for v, k in zip(getattr(self, name), mask, strict=True) if k])
        for name in ("template", "taxel", "rows", "xyz", "has_row", "trusted"):
            setattr(self, name, getattr(self, name)[ch])


def _rows_text(rows: list[int] | NDArray, pos: PositionsFile) -> str:
    rows = [int(r) for r in rows]
    shown = ", ".join(f"{r} (line {pos.line(r)})" for r in rows[:4])
    return shown + (f" and {len(rows) - 4} more" if len(rows) > 4 else "")


def resolve_addresses(
    ini: SkinGuiIni,
    n_boards: int,
    boards: tuple[int, ...] | None,
    boards_source: str,
    spec: SkinSpec | None,
    report: ImportReport,
) -> tuple[int, ...]:
    """CAN address of each board index (slot // 16), from ``boards`` if given, else the
    .ini's cardid (reordered to match the skin spec's enabled triangles when a spec is
    given, since cardid lines can be stale); raises ValueError when there are too few."""
    card = ini.cardid
    if boards is not None:
        if len(boards) < n_boards:
            raise ValueError(
                f"{boards_source} lists {len(boards)} board address(es) but the slots of "
                f"{ini.path} reach board index {n_boards - 1} (slot // 16): give {n_boards}"
            )
        if card is not None and tuple(card[: len(boards)]) != tuple(boards):
            report.add(
                "stale_cardid",
                f"{ini.path}:{ini.cardid_line}: cardid {' '.join(map(str, card))} differs "
                f"from {boards_source} ({' '.join(map(str, boards))}); using the latter "
                "(the GUI only uses cardid in its direct-CAN mode)",
            )
        report.address_source = boards_source
        return tuple(boards)
    if card is None:
        raise ValueError(f"{ini.path} has no cardid line: give the board addresses with --boards")
    if len(card) < n_boards:
        raise ValueError(
            f"{ini.path}:{ini.cardid_line}: cardid lists {len(card)} address(es) but the "
            f"slots reach board index {n_boards - 1} (slot // 16): the line is stale; give "
            f"the {n_boards} addresses in slot order with --boards"
        )
    if spec is None:
        report.notes.append(
            f"WARNING: board addresses from the cardid line ({ini.path}:{ini.cardid_line}), "
            "which the GUI only uses in its direct-CAN mode and may be stale or in the wrong "
            "order; confirm them with --boards (the robot's skin.xml and wrapper) or "
            "--skin-spec"
        )
        report.address_source = f"cardid, line {ini.cardid_line}"
        return tuple(card)
    # The order of cardid's addresses that enables the most of the .ini's triangles.
    wanted = [{s.slot % 16 for s in ini.sensors if s.slot // 16 == b} for b in range(len(card))]

    def score(order: tuple[int, ...]) -> int:
        return sum(len(w & spec.enabled_triangles(a)) for w, a in zip(wanted, order, strict=True))

    best = max(itertools.permutations(card), key=lambda o: (score(o), o == card))
    if best != card and score(best) > score(card):
        report.add(
            "stale_cardid",
            f"{ini.path}:{ini.cardid_line}: cardid {' '.join(map(str, card))} is in the wrong "
            f"order: the skin spec enables the .ini's triangles when the boards are "
            f"{' '.join(map(str, best))} ({score(best)} of "
            f"{sum(map(len, wanted))} enabled, against {score(card)}); using that order",
        )
        report.address_source = "cardid reordered to match the skin spec"
        return best
    report.address_source = f"cardid, line {ini.cardid_line}, consistent with the skin spec"
    return card


def gather(
    ini: SkinGuiIni,
    pos: PositionsFile,
    boards: tuple[int, ...] | None,
    boards_source: str,
    spec: SkinSpec | None,
    report: ImportReport,
) -> list[Item]:
    """The .ini's modules with their rows, checked against each other (see module doc)."""
    ini_p, pos_p = ini.path, pos.path
    # Types first: an unknown one is an error, a known unsupported one is left out.
    taken: dict[int, IniSensor] = {}
    chosen: list[tuple[IniSensor, GuiType]] = []
    skipped: list[IniSensor] = []
    for s in ini.sensors:
        if s.type in UNSUPPORTED:
            skipped.append(s)
            report.skipped.append(
                f"{ini_p}:{s.line}: {s.type} at slot {s.slot}: {UNSUPPORTED[s.type]}"
            )
        elif s.type not in SUPPORTED:
            raise IcubFileError(
                ini_p,
                s.line,
                f"unknown sensor type {s.type!r} (known: {', '.join(known_types())})",
            )
        else:
            chosen.append((s, SUPPORTED[s.type]))
            if s.layout_num:
                report.add(
                    "layout_num",
                    f"{ini_p}:{s.line}: layoutNum {s.layout_num} (the GUI draws channel k at "
                    "11 - k): a drawing option, ignored; the CAN channel order is the module "
                    "type's",
                    slot=s.slot,
                )
        span = SUPPORTED[s.type].slots if s.type in SUPPORTED else 1
        for k in range(span):
            if s.slot + k in taken:
                other = taken[s.slot + k]
                raise IcubFileError(
                    ini_p,
                    s.line,
                    f"{s.type} at slot {s.slot} occupies slots {s.slot}..{s.slot + span - 1}, "
                    f"overlapping the {other.type} of line {other.line} (slot {other.slot})",
                )
            taken[s.slot + k] = s
    if not chosen:
        first = skipped[0] if skipped else None
        raise IcubFileError(
            ini_p,
            first.line if first else None,
            "no sensor of a type this importer can model"
            + (
                f" (only {', '.join(sorted({k.type for k in skipped}))}: {UNSUPPORTED[first.type]})"
                if first
                else ""
            ),
        )
    n_boards = max(taken) // 16 + 1
    addresses = resolve_addresses(ini, n_boards, boards, boards_source, spec, report)
    report.addresses = addresses

    n_rows = len(pos.rows)
    expected = ROWS_PER_BOARD * len(addresses)
    if n_rows != expected:
        fix = (
            f"rows {expected}.. are extra (first: line {pos.line(expected)})"
            if n_rows > expected
            else f"{expected - n_rows} row(s) missing after line {pos.line(n_rows - 1)}"
        )
        raise IcubFileError(
            pos_p,
            pos.line(expected) if n_rows > expected else pos.line(n_rows - 1),
            f"{n_rows} calibration rows, expected {expected} = 192 per board × "
            f"{len(addresses)} board(s) ({report.address_source}): {fix}",
        )
    data = ~pos.empty
    stray = [r for r in np.flatnonzero(data) if r // ROWS_PER_SLOT not in taken]
    if stray:
        slots = sorted({r // ROWS_PER_SLOT for r in stray})
        raise IcubFileError(
            pos_p,
            pos.line(stray[0]),
            f"rows {_rows_text(stray, pos)} hold taxels of slot(s) "
            f"{[int(s) for s in slots]}, which {ini_p} does not list: the positions file does "
            "not match the .ini",
        )
    if data[-1]:
        report.add(
            "last_row",
            f"{pos_p}:{pos.line(n_rows - 1)}: the last row holds data, but skinDynLib's "
            "skinPart never reads the last row; used here as written",
            rows=[n_rows - 1],
        )

    items: list[Item] = []
    for s, g in chosen:
        slots = list(range(s.slot, s.slot + g.slots))
        types = [MODULE_TYPES[t] for t in g.modules]
        rows = np.arange(s.slot * ROWS_PER_SLOT, (s.slot + g.slots) * ROWS_PER_SLOT)
        item = Item(
            sensor=s,
            gui=g,
            slots=slots,
            types=types,
            addresses=[addresses[sl // 16] for sl in slots],
            triangles=[sl % 16 for sl in slots],
            template=np.concatenate([t.channel_xy for t in types]),
            taxel=np.concatenate([t.taxel_mask for t in types]),
            rows=rows,
            xyz=pos.positions[rows].copy(),
            has_row=data[rows].copy(),
            trusted=np.zeros(len(rows), dtype=bool),
        )
        _apply_spec(item, spec, report)
        if item.slots:
            items.append(item)
    if not items:
        raise ValueError("the skin spec disables every module of the .ini: nothing to import")
    if not any(it.has_row[it.taxel].any() for it in items):
        raise IcubFileError(
            pos_p,
            None,
            f"no row holds a taxel of any module of {ini_p}: the positions file does not "
            "match the .ini",
        )
    taxel_rows = np.zeros(n_rows, dtype=bool)
    for it in items:
        taxel_rows[it.rows[it.taxel]] = True
    _check_repr(pos, data & taxel_rows, report)
    _trust_rows(items, pos, report)
    _check_normals(items, pos, report)
    return items


def _check_repr(pos: PositionsFile, taxels: NDArray[np.bool_], report: ImportReport) -> None:
    """taxel2Repr against the rows: its length, and taxel rows with data it calls dummies."""
    t2r = pos.taxel2repr
    if t2r is None:
        report.add("taxel2repr_missing", f"{pos.path}: no taxel2Repr list (not needed here)")
        return
    if len(t2r) != len(pos.rows):
        report.add(
            "taxel2repr_length",
            f"{pos.path}:{pos.taxel2repr_line}: taxel2Repr has {len(t2r)} entries for "
            f"{len(pos.rows)} rows; only its first {min(len(t2r), len(pos.rows))} are read",
        )
    marks = np.full(len(pos.rows), -1, dtype=np.int64)
    n = min(len(t2r), len(pos.rows))
    marks[:n] = t2r[:n]
    # Markers: -1 dummy, -2 thermal pad, k ≥ 0 a taxel (k: its triangle's centre row).
    said_dummy = np.flatnonzero(taxels & (marks < 0))
    for slot, grp in itertools.groupby(said_dummy, key=lambda r: r // ROWS_PER_SLOT):
        rows = list(grp)
        report.add(
            "taxel2repr_marker",
            f"{pos.path}: slot {slot}: rows {_rows_text(rows, pos)} hold positions but "
            f"taxel2Repr marks them {sorted({int(marks[r]) for r in rows})} (dummy or "
            "thermal pad) where the .ini's module type has taxels; the module type decides",
            slot=slot,
            rows=rows,
        )


def _apply_spec(item: Item, spec: SkinSpec | None, report: ImportReport) -> None:
    n = len(item.slots)
    if spec is None:
        item.shift, item.cdc_offset, item.no_load = [None] * n, [None] * n, [None] * n
        return
    cfg = [spec.triangle(a, t) for a, t in zip(item.addresses, item.triangles, strict=True)]
    keep = [c.enabled for c in cfg]
    for sl, a, t, c in zip(item.slots, item.addresses, item.triangles, cfg, strict=True):
        if not c.enabled:
            report.add(
                "disabled_in_spec",
                f"slot {sl} (board {a} triangle {t}, {item.sensor.type} of line "
                f"{item.sensor.line}) is not enabled in {spec.path} (line {c.line}): left out",
                slot=sl,
            )
    item.shift = [c.shift for c in cfg]
    item.cdc_offset = [c.cdc_offset for c in cfg]
    item.no_load = [spec.board(a).no_load for a in item.addresses]
    item.keep(keep)


def _trust_rows(items: list[Item], pos: PositionsFile, report: ImportReport) -> None:
    """Mark each taxel row trusted unless empty or a copy of another row."""
    keys: dict[tuple[int, int, int], list[tuple[Item, int]]] = {}
    for it in items:
        for ch in np.flatnonzero(it.has_row):
            key = tuple(np.round(it.xyz[ch] / SAME_POSITION).astype(np.int64).tolist())
            keys.setdefault(key, []).append((it, int(ch)))  # type: ignore[arg-type]
    for it in items:
        it.trusted = it.taxel & it.has_row
    centre_copies: dict[int, list[int]] = {}
    for group in keys.values():
        if len(group) < 2:
            continue
        owners = {id(it) for it, _ in group}
        it0, _ = group[0]
        oc = it0.origin_channel
        origin = [(it, ch) for it, ch in group if ch == it.origin_channel]
        if len(owners) == 1 and oc is not None and origin:
            # Rows copied from the triangle centre (positions generated by interpolation,
            # taxels outside the interpolation's hull given the centre): the centre stays.
            for it, ch in group:
                if ch != oc:
                    it.trusted[ch] = False
                    centre_copies.setdefault(it.slots[0], []).append(int(it.rows[ch]))
            continue
        rows = [int(it.rows[ch]) for it, ch in group]
        for it, ch in group:
            it.trusted[ch] = False
        report.add(
            "duplicate_rows",
            f"{pos.path}: rows {_rows_text(rows, pos)} hold the same position; none of them "
            "is used to place or check its module",
            slot=group[0][0].slots[0],
            rows=rows,
        )
    for slot, rows in sorted(centre_copies.items()):
        report.add(
            "centre_copies",
            f"{pos.path}: slot {slot}: rows {_rows_text(sorted(rows), pos)} are copies of the "
            f"triangle centre row {ROWS_PER_SLOT * slot + 3}; only the rows of their own "
            "place the module",
            slot=slot,
            rows=sorted(rows),
        )
    for it in items:
        ch = np.flatnonzero(it.trusted)
        if len(ch) < 3:
            continue
        off = np.linalg.norm(it.xyz[ch] - np.median(it.xyz[ch], axis=0), axis=1)
        far = off > ROW_SPREAD_M
        if far.any() and np.count_nonzero(~far) >= 3:
            it.trusted[ch[far]] = False
            rows = it.rows[ch[far]]
            report.add(
                "outlier_rows",
                f"{pos.path}: slot {it.slots[0]}: rows {_rows_text(rows, pos)} lie "
                f"{off[far].max() * 1e3:.0f} mm from the module's other rows (more than "
                f"{ROW_SPREAD_M * 1e3:.0f} mm): mistyped? not used to place or check it",
                slot=it.slots[0],
                rows=rows.tolist(),
            )
    for it in items:
        empty = np.flatnonzero(it.taxel & ~it.has_row)
        if it.has_row.any() and len(empty):
            rows = it.rows[empty]
            report.add(
                "empty_rows",
                f"{pos.path}: slot {it.slots[0]} ({it.sensor.type}): taxel rows "
                f"{_rows_text(rows, pos)} are empty; the channels stay in the layout, "
                "placed by the module's other rows",
                slot=it.slots[0],
                rows=rows.tolist(),
            )
        elif not it.has_row.any():
            report.add(
                "no_rows",
                f"{pos.path}: slot {it.slots[0]} ({it.sensor.type} of line {it.sensor.line}) "
                f"has no row (rows {it.rows[0]}..{it.rows[-1]} are empty): placed from the .ini",
                slot=it.slots[0],
                rows=it.rows.tolist(),
            )


def _check_normals(items: list[Item], pos: PositionsFile, report: ImportReport) -> None:
    rows = np.concatenate([it.rows[it.has_row] for it in items])
    n = pos.normals[rows]
    if len(n) == 0:
        return
    if np.allclose(n, n[0], atol=1e-9):
        report.add(
            "constant_normals",
            f"{pos.path}: the normals column is the constant ({', '.join(f'{v:g}' for v in n[0])}"
            f") on all {len(n)} rows with data: ignored; normals come from the fitted surface",
        )
