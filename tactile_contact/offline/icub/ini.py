"""Reader of an iCub skinGui ``.ini`` (icub-main ``app/skinGui/conf/skinGui/*.ini``).

The file is a YARP configuration: ``key value...`` lines (``cardid 13 12``, ``robotPart
left_forearm``, ...), then a ``[SENSORS]`` group with one line per sensor::

    <type> <id> <X> <Y> <Orient_deg> [<Gain> [<Mirror> [<layoutNum>]]]

parsed as icub-main ``src/tools/iCubSkinGui/plugin/SkinMeshThreadPort.cpp`` does: ``id`` is
the slot (data index ``12·id + channel``), X and Y are GUI units (about a millimetre, y up),
Orient is counter-clockwise in degrees, Mirror (0/1, default 0) mirrors the drawing about the
sensor's y axis before rotating, Gain is display brightness. Missing trailing fields default
to 0 as YARP's ``get(i).asInt32()`` does. ``#`` and ``//`` start comments.

Every problem is an :class:`~tactile_contact.offline.icub.errors.IcubFileError` naming the file
and line: no ``[SENSORS]`` group, a non-numeric or missing field, a slot out of range, a slot
listed twice, a Mirror other than 0 or 1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

from tactile_contact.offline.icub.errors import IcubFileError

#: Slots a skin part can address: 16 boards × 16 triangles (the port vector of one part).
MAX_SLOTS = 256


@dataclass(frozen=True)
class IniSensor:
    """One ``[SENSORS]`` line.

    Attributes:
        type: GUI type name (``triangle_10pad``, ``palmL``, ``fingertip2L``, ...).
        slot: the ``id`` column: data index ``12·slot + channel``; board index ``slot // 16``.
        x, y: GUI position [GUI units ≈ 1 mm], y up.
        orient_deg: counter-clockwise rotation [deg].
        gain: display gain (unused here).
        mirror: the GUI draws the sensor mirrored (x → −x before rotating).
        layout_num: alternative channel order of the drawing (1: channel k at 11 − k).
        line: 1-based line number in the file.
        path: the .ini file it was read from (for error messages).
    """

    type: str
    slot: int
    x: float
    y: float
    orient_deg: float
    gain: float
    mirror: bool
    layout_num: int
    line: int
    path: str = ""


@dataclass(frozen=True)
class SkinGuiIni:
    """A parsed skinGui ``.ini``.

    Attributes:
        path: the file.
        sensors: the ``[SENSORS]`` lines in file order.
        cardid: the ``cardid`` addresses (may be stale: see docs/icub.md), or None.
        cardid_line: its line number, or None.
        robot_part: the ``robotPart`` value (e.g. ``left_forearm``), or None.
    """

    path: str
    sensors: tuple[IniSensor, ...]
    cardid: tuple[int, ...] | None
    cardid_line: int | None
    robot_part: str | None


def _strip_comment(text: str) -> str:
    for mark in ("#", "//"):
        cut = text.find(mark)
        if cut >= 0:
            text = text[:cut]
    return text.strip()


def _number(path: str, line: int, what: str, token: str, integer: bool = False) -> float:
    try:
        value = int(token, 0) if integer else float(token)
    except ValueError:
        kind = "an integer" if integer else "a number"
        raise IcubFileError(path, line, f"{what}: expected {kind}, got {token!r}") from None
    if not math.isfinite(value):
        raise IcubFileError(path, line, f"{what}: must be finite, got {token!r}")
    return value


def read_ini(path: str | Path) -> SkinGuiIni:
    """Read a skinGui ``.ini``; raises IcubFileError (file and line) on any problem."""
    p = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8-sig", errors="replace")
    except OSError as exc:
        raise IcubFileError(p, None, f"cannot read: {exc.strerror or exc}") from None
    sensors: list[IniSensor] = []
    seen: dict[int, int] = {}
    cardid: tuple[int, ...] | None = None
    cardid_line: int | None = None
    robot_part: str | None = None
    group: str | None = None
    found_sensors = False
    for n, raw in enumerate(text.splitlines(), start=1):
        body = _strip_comment(raw)
        if not body:
            continue
        if body.startswith("["):
            if not body.endswith("]"):
                raise IcubFileError(p, n, f"unterminated group header {body!r}")
            group = body[1:-1].strip()
            found_sensors |= group == "SENSORS"
            continue
        tok = body.split()
        if group is None:
            if tok[0] == "cardid":
                if len(tok) < 2:
                    raise IcubFileError(p, n, "cardid: expected one or more CAN addresses")
                cardid = tuple(int(_number(p, n, "cardid", t, integer=True)) for t in tok[1:])
                bad = [a for a in cardid if not 0 <= a <= 15]
                if bad:
                    raise IcubFileError(p, n, f"cardid: CAN address {bad[0]} outside 0..15")
                cardid_line = n
            elif tok[0] == "robotPart" and len(tok) > 1:
                robot_part = tok[1]
            continue
        if group != "SENSORS":
            continue
        if len(tok) < 5:
            raise IcubFileError(
                p,
                n,
                f"sensor line has {len(tok)} field(s); expected "
                "'type id X Y Orient [Gain [Mirror [layoutNum]]]'",
            )
        if len(tok) > 8:
            raise IcubFileError(p, n, f"sensor line has {len(tok)} fields; at most 8 are defined")
        fields = [*tok, "0", "0", "0"][:8]
        slot = int(_number(p, n, "id", fields[1], integer=True))
        if not 0 <= slot < MAX_SLOTS:
            raise IcubFileError(p, n, f"id {slot} outside 0..{MAX_SLOTS - 1}")
        if slot in seen:
            raise IcubFileError(
                p, n, f"slot {slot} listed twice (also line {seen[slot]}); the GUI rejects it"
            )
        seen[slot] = n
        mirror = int(_number(p, n, "Mirror", fields[6], integer=True))
        if mirror not in (0, 1):
            raise IcubFileError(p, n, f"Mirror: expected 0 or 1, got {fields[6]!r}")
        sensors.append(
            IniSensor(
                type=fields[0],
                slot=slot,
                x=_number(p, n, "X", fields[2]),
                y=_number(p, n, "Y", fields[3]),
                orient_deg=_number(p, n, "Orientation", fields[4]),
                gain=_number(p, n, "Gain", fields[5]),
                mirror=bool(mirror),
                layout_num=int(_number(p, n, "layoutNum", fields[7], integer=True)),
                line=n,
                path=str(p),
            )
        )
    if not found_sensors:
        raise IcubFileError(p, None, "no [SENSORS] group: not a skinGui .ini file")
    if not sensors:
        raise IcubFileError(p, None, "the [SENSORS] group lists no sensor")
    return SkinGuiIni(p, tuple(sensors), cardid, cardid_line, robot_part)
