"""Reader of an iCub skin positions file (icub-main ``app/skinGui/conf/positions/*.txt``).

The file is a YARP configuration read by skinDynLib's ``skinPart::setTaxelPosesFromFile``::

    name             l_forearm              # the robot link the positions are in
    spatial_sampling taxel
    taxel2Repr       ( 3 3 3 ... -1 ... )   # per row: -1 dummy, -2 thermal pad, else a centre row
    [calibration]
    x y z nx ny nz                          # one row per port index, metres
    ...

Row k is port index k: board index ``k // 192``, triangle ``(k % 192) // 12``, channel
``k % 12``. A row whose position and normal are all zero means "no taxel". The reader only
parses; what the rows mean (duplicates, mirrored patterns, bogus normals) is judged by the
importer. Every problem is an IcubFileError naming file and line: no ``[calibration]`` group,
a row without six numbers (a truncated file), a non-numeric or non-finite field, positions
that cannot be metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from tactile_contact.offline.icub.errors import IcubFileError

#: A coordinate beyond this [m] cannot be a position on a robot in metres (a file in mm?).
MAX_COORDINATE_M = 2.0


@dataclass(frozen=True)
class PositionsFile:
    """A parsed positions file.

    Attributes:
        path: the file.
        link: the ``name`` value (the link frame, e.g. ``l_forearm``), or None.
        spatial_sampling: ``taxel`` or ``triangle`` (None if absent).
        taxel2repr: the ``taxel2Repr`` list (any length), or None.
        taxel2repr_line: its line number, or None.
        rows: (N, 6) position [m] and normal of each row, in file order.
        row_lines: (N,) 1-based line number of each row.
    """

    path: str
    link: str | None
    spatial_sampling: str | None
    taxel2repr: tuple[int, ...] | None
    taxel2repr_line: int | None
    rows: NDArray[np.float64]
    row_lines: NDArray[np.int64]

    @property
    def positions(self) -> NDArray[np.float64]:
        """(N, 3) row positions [m]."""
        return self.rows[:, :3]

    @property
    def normals(self) -> NDArray[np.float64]:
        """(N, 3) row normals as written (often a bogus constant: never trusted alone)."""
        return self.rows[:, 3:]

    @property
    def empty(self) -> NDArray[np.bool_]:
        """(N,) True for rows of zeros (no taxel)."""
        return ~np.any(self.rows != 0.0, axis=1)

    def line(self, row: int) -> int:
        """Line number of row ``row`` (0-based port index)."""
        return int(self.row_lines[row])


def _strip_comment(text: str) -> str:
    for mark in ("#", "//"):
        cut = text.find(mark)
        if cut >= 0:
            text = text[:cut]
    return text.strip()


def read_positions(path: str | Path) -> PositionsFile:
    """Read a positions ``.txt``; raises IcubFileError (file and line) on any problem."""
    p = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8-sig", errors="replace")
    except OSError as exc:
        raise IcubFileError(p, None, f"cannot read: {exc.strerror or exc}") from None
    link = sampling = None
    repr_tokens: list[str] | None = None
    repr_line: int | None = None
    in_repr = False
    group: str | None = None
    found_calibration = False
    rows: list[list[float]] = []
    lines: list[int] = []
    for n, raw in enumerate(text.splitlines(), start=1):
        body = _strip_comment(raw)
        if in_repr:  # a taxel2Repr list continued over several lines
            assert repr_tokens is not None
            close = body.find(")")
            repr_tokens += (body if close < 0 else body[:close]).split()
            in_repr = close < 0
            continue
        if not body:
            continue
        if body.startswith("["):
            if not body.endswith("]"):
                raise IcubFileError(p, n, f"unterminated group header {body!r}")
            group = body[1:-1].strip()
            if group == "calibration":
                if found_calibration:
                    raise IcubFileError(p, n, "a second [calibration] group")
                found_calibration = True
            continue
        tok = body.split()
        if group is None:
            key = tok[0]
            if key == "name" and len(tok) > 1:
                link = tok[1]
            elif key == "spatial_sampling" and len(tok) > 1:
                sampling = tok[1]
            elif key == "taxel2Repr":
                rest = body[len(key) :].strip()
                if not rest.startswith("("):
                    raise IcubFileError(p, n, "taxel2Repr: expected a list '( ... )'")
                close = rest.find(")")
                repr_tokens = (rest[1:] if close < 0 else rest[1:close]).split()
                repr_line, in_repr = n, close < 0
            continue
        if group != "calibration":
            continue
        if len(tok) != 6:
            raise IcubFileError(
                p,
                n,
                f"calibration row {len(rows)} has {len(tok)} field(s); expected 6 "
                "(x y z nx ny nz): truncated or malformed",
            )
        values = []
        for k, t in enumerate(tok):
            try:
                v = float(t)
            except ValueError:
                what = ("x", "y", "z", "nx", "ny", "nz")[k]
                raise IcubFileError(
                    p, n, f"calibration row {len(rows)}, {what}: expected a number, got {t!r}"
                ) from None
            if not math.isfinite(v):
                raise IcubFileError(p, n, f"calibration row {len(rows)}: non-finite {t!r}")
            values.append(v)
        if max(abs(v) for v in values[:3]) > MAX_COORDINATE_M:
            raise IcubFileError(
                p,
                n,
                f"calibration row {len(rows)}: position {values[:3]} is beyond "
                f"{MAX_COORDINATE_M:g} m: positions files are in metres",
            )
        rows.append(values)
        lines.append(n)
    if in_repr:
        raise IcubFileError(p, repr_line, "taxel2Repr: list not closed with ')' (truncated?)")
    if not found_calibration:
        raise IcubFileError(
            p, None, "no [calibration] group: not a positions file (or the old format)"
        )
    if not rows:
        raise IcubFileError(p, None, "the [calibration] group has no rows")
    t2r: tuple[int, ...] | None = None
    if repr_tokens is not None:
        try:
            t2r = tuple(int(t) for t in repr_tokens)
        except ValueError:
            bad = next(t for t in repr_tokens if not t.lstrip("-").isdigit())
            raise IcubFileError(
                p, repr_line, f"taxel2Repr: expected integers, got {bad!r}"
            ) from None
    return PositionsFile(
        p,
        link,
        sampling,
        t2r,
        repr_line,
        np.asarray(rows, dtype=np.float64).reshape(-1, 6),
        np.asarray(lines, dtype=np.int64),
    )
