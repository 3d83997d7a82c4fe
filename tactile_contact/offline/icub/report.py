"""What the iCub importer found and did, for the command's printout and for tests.

Three parts: the anomalies in the input files (each with the slot and rows it concerns, and
what was done about it), the source of every module's placement (3-D rows or the .ini), and
per patch the flattening's figures: the fitted surface and how far in-plane distances between
neighbouring taxels differ from their 3-D distances (docs/icub.md explains each line).
"""

from __future__ import annotations

from dataclasses import dataclass, field

#: Targets of the flattening's neighbour-distance error [m] (issue 24): median and 95th pct.
TARGET_MEDIAN = 1.5e-3
TARGET_P95 = 4.0e-3


@dataclass(frozen=True)
class Anomaly:
    """One thing in the files that is wrong or surprising, and how it was absorbed.

    Attributes:
        kind: short identifier (e.g. ``centre_copies``, ``mirrored_pattern``,
            ``stale_cardid``, ``constant_normals``); docs/icub.md lists them.
        message: the sentence printed, naming slot, rows and lines.
        slot: the slot concerned, if one.
        rows: the positions-file rows concerned (0-based port indices).
    """

    kind: str
    message: str
    slot: int | None = None
    rows: tuple[int, ...] = ()


@dataclass(frozen=True)
class ModulePlacement:
    """Where one module's placement came from.

    Attributes:
        slot: the slot (port index // 12).
        board: CAN address; triangle: triangle on the board.
        type: module type name.
        patch: the patch it went to.
        position_source: ``3-D`` or ``.ini``.
        rotation_source: ``3-D`` or ``.ini``.
        taxels_3d: taxel rows of the module trusted and used for its fit.
        fit_rms: rms distance [m] of those rows from the placed template (None: no fit).
        note: why the .ini was used, or "" .
    """

    slot: int
    board: int
    triangle: int
    type: str
    patch: str
    position_source: str
    rotation_source: str
    taxels_3d: int
    fit_rms: float | None
    note: str = ""


@dataclass(frozen=True)
class PatchFigures:
    """The flattening of one patch.

    Attributes:
        name: patch name; shape: ``cylinder`` or ``plane``.
        radius: fitted cylinder radius [m] (None for a plane).
        surface_rms, surface_worst: distance of the taxel rows from the fitted surface [m].
        modules, taxels: counts.
        pairs: neighbouring taxel pairs compared (3-D distance ≤ NEIGHBOUR_DISTANCE).
        median, p95, worst: |in-plane − 3-D distance| over those pairs [m].
    """

    name: str
    shape: str
    radius: float | None
    surface_rms: float
    surface_worst: float
    modules: int
    taxels: int
    pairs: int
    median: float
    p95: float
    worst: float

    @property
    def within_targets(self) -> bool:
        return self.pairs > 0 and self.median <= TARGET_MEDIAN and self.p95 <= TARGET_P95


@dataclass
class ImportReport:
    """Everything the import has to say (see :meth:`lines`)."""

    sources: list[str] = field(default_factory=list)
    addresses: tuple[int, ...] = ()
    address_source: str = ""
    anomalies: list[Anomaly] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    modules: list[ModulePlacement] = field(default_factory=list)
    patches: list[PatchFigures] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def add(self, kind: str, message: str, slot: int | None = None, rows=()) -> None:
        """Record an anomaly."""
        self.anomalies.append(Anomaly(kind, message, slot, tuple(int(r) for r in rows)))

    def kinds(self) -> set[str]:
        """The kinds of anomaly recorded."""
        return {a.kind for a in self.anomalies}

    def lines(self) -> list[str]:
        """The report as printed by ``tactile-contact-import-icub``."""
        out = [f"read {s}" for s in self.sources]
        out.append(
            f"boards (slot // 16 -> CAN address): "
            f"{', '.join(f'{i}->{a}' for i, a in enumerate(self.addresses))} "
            f"({self.address_source})"
        )
        out += [f"note: {n}" for n in self.notes]
        for s in self.skipped:
            out.append(f"skipped: {s}")
        out.append(f"anomalies ({len(self.anomalies)}), each absorbed as said:")
        out += [f"  [{a.kind}] {a.message}" for a in self.anomalies] or ["  none"]
        out.append("modules (position / rotation from):")
        for m in self.modules:
            fit = f", rms {m.fit_rms * 1e3:.2f} mm" if m.fit_rms is not None else ""
            note = f" ({m.note})" if m.note else ""
            out.append(
                f"  slot {m.slot:3d} board {m.board:2d} triangle {m.triangle:2d} {m.type} -> "
                f"{m.patch}: position {m.position_source}, rotation {m.rotation_source}, "
                f"{m.taxels_3d} taxel rows{fit}{note}"
            )
        out.append(
            "patches (neighbouring taxels: |in-plane - 3-D distance|; targets median "
            f"<= {TARGET_MEDIAN * 1e3:g} mm, p95 <= {TARGET_P95 * 1e3:g} mm):"
        )
        for p in self.patches:
            shape = f"cylinder R = {p.radius * 1e3:.1f} mm" if p.radius else "plane"
            verdict = "within targets" if p.within_targets else "OUTSIDE TARGETS"
            out.append(
                f"  {p.name}: {p.modules} modules, {p.taxels} taxels, {shape} "
                f"(rows off the surface: rms {p.surface_rms * 1e3:.2f}, worst "
                f"{p.surface_worst * 1e3:.2f} mm); {p.pairs} pairs: median "
                f"{p.median * 1e3:.2f}, p95 {p.p95 * 1e3:.2f}, worst {p.worst * 1e3:.2f} mm "
                f"({verdict})"
            )
        return out
