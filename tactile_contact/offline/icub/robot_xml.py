"""Readers of a robot's skin configuration (robotology/robots-configuration XML files).

Three files describe one body bus of a robot (e.g. iCubGenova07's left arm):

- ``hardware/skin/<part>-ebX-skinSpec.xml``: board settings (``defaultCfgBoard``,
  ``specialCfgBoards`` rows ``patch addrStart addrEnd period skinType noLoad``) and triangle
  settings (``defaultCfgTriangle``: enabled, shift, cdcOffset; ``specialCfgTriangles`` rows
  ``patch addr first last enabled shift cdcOffset``; later rows override earlier ones);
- ``hardware/skin/<part>-ebX-skin.xml``: the CAN addresses in port order
  (``skinCanAddrsPatch1``, ``skinCanAddrsPatch2``; patch-2 boards come first in the vector,
  icub-main embObjSkin.cpp);
- ``wrappers/skin/<part>-skin_wrapper.xml``: the slices of that vector per YARP port
  (``<elem name="left_forearm"> 192 575 0 383 </elem>``).

XML comments are ignored (the leg specs keep whole groups commented out). Every problem is an
IcubFileError naming the file and the line of the element at fault: malformed XML, a missing
group or parameter, a row with the wrong number of fields, a non-numeric value.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from xml.parsers import expat

from tactile_contact.offline.icub.errors import IcubFileError


@dataclass(frozen=True)
class _Param:
    group: str  # name of the innermost enclosing <group>/<paramlist> ("" at top level)
    name: str
    text: str
    line: int


@dataclass(frozen=True)
class BoardConfig:
    """SET_BRD_CFG values of one board: period [ms], skinType, noLoad [8-bit counts]."""

    period_ms: int
    skin_type: int
    no_load: int


@dataclass(frozen=True)
class TriangleConfig:
    """SET_TRIANG_CFG values of one triangle: enabled, shift [bits], cdcOffset [CDC counts];
    ``line`` is the spec line they come from."""

    enabled: bool
    shift: int
    cdc_offset: int
    line: int


@dataclass(frozen=True)
class SkinSpec:
    """A parsed skinSpec: defaults plus the special rows, resolved per address."""

    path: str
    default_board: BoardConfig
    default_triangle: TriangleConfig
    boards: dict[int, BoardConfig]  # address → special board settings
    triangles: dict[tuple[int, int], TriangleConfig]  # (address, triangle) → special

    def board(self, address: int) -> BoardConfig:
        """Settings of the board at CAN ``address``."""
        return self.boards.get(address, self.default_board)

    def triangle(self, address: int, triangle: int) -> TriangleConfig:
        """Settings of ``triangle`` on the board at CAN ``address``."""
        return self.triangles.get((address, triangle), self.default_triangle)

    def enabled_triangles(self, address: int) -> frozenset[int]:
        """Triangles 0..15 enabled on the board at ``address``."""
        return frozenset(t for t in range(16) if self.triangle(address, t).enabled)


def _params(path: str) -> list[_Param]:
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise IcubFileError(path, None, f"cannot read: {exc.strerror or exc}") from None
    parser = expat.ParserCreate()
    out: list[_Param] = []
    stack: list[tuple[str, str, int]] = []  # (tag, name attribute, line)
    text: list[str] = []

    def start(tag: str, attrs: dict[str, str]) -> None:
        stack.append((tag, attrs.get("name", ""), parser.CurrentLineNumber))
        text.clear()

    def end(tag: str) -> None:
        tag_, name, line = stack.pop()
        if tag_ in ("param", "elem"):
            group = next((n for t, n, _ in reversed(stack) if t in ("group", "paramlist")), "")
            out.append(_Param(group, name, "".join(text).strip(), line))
        text.clear()

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    parser.CharacterDataHandler = text.append
    try:
        parser.Parse(data, True)
    except expat.ExpatError as exc:
        raise IcubFileError(
            path, exc.lineno, f"not well-formed XML: {expat.ErrorString(exc.code)}"
        ) from None
    return out


def _int(path: str, p: _Param, token: str, what: str) -> int:
    try:
        return int(token, 0)
    except ValueError:
        raise IcubFileError(
            path, p.line, f"{p.name}: {what}: expected an integer, got {token!r}"
        ) from None


def _ranged(path: str, p: _Param, token: str, what: str, lo: int, hi: int) -> int:
    """An integer field within [lo, hi] (what the boards' configuration messages carry)."""
    v = _int(path, p, token, what)
    if not lo <= v <= hi:
        said = token if token == str(v) else f"{token} = {v}"
        where = p.name if p.name == what else f"{p.name}: {what}"
        raise IcubFileError(path, p.line, f"{where} {said} outside {lo}..{hi}")
    return v


#: Field ranges of the boards' configuration (SET_BRD_CFG / SET_TRIANG_CFG, docs/can_protocol.md).
_RANGES = {
    "period": (1, 255),
    "skinType": (0, 15),
    "noLoad": (0, 255),
    "shift": (0, 15),
    "cdcOffset": (0, 0xFFFF),
    "addrStart": (0, 15),
    "addrEnd": (0, 15),
    "addr": (0, 15),
}


def _field(path: str, p: _Param, token: str, what: str) -> int:
    lo, hi = _RANGES.get(what, (-(2**31), 2**31 - 1))
    return _ranged(path, p, token, what, lo, hi)


def _bool(path: str, p: _Param, token: str, what: str) -> bool:
    t = token.strip().lower()
    if t in ("true", "1"):
        return True
    if t in ("false", "0"):
        return False
    raise IcubFileError(path, p.line, f"{p.name}: {what}: expected true or false, got {token!r}")


def _group(path: str, params: list[_Param], group: str, required: bool) -> dict[str, _Param]:
    found = {p.name: p for p in params if p.group == group}
    if required and not found:
        raise IcubFileError(
            path, None, f'no <group name="{group}"> with parameters: not a skinSpec file?'
        )
    return found


def _need(path: str, group: dict[str, _Param], name: str, where: str) -> _Param:
    if name not in group:
        line = min((p.line for p in group.values()), default=None)
        raise IcubFileError(path, line, f'group {where}: missing <param name="{name}">')
    return group[name]


def read_skin_spec(path: str | Path) -> SkinSpec:
    """Read a ``*-skinSpec.xml``; raises IcubFileError (file and line) on any problem."""
    p = str(path)
    params = _params(p)
    db = _group(p, params, "defaultCfgBoard", True)
    dt = _group(p, params, "defaultCfgTriangle", True)

    def one(group: dict[str, _Param], name: str, where: str) -> tuple[_Param, str]:
        q = _need(p, group, name, where)
        return q, q.text

    default_board = BoardConfig(
        *(
            _field(p, q, t, name)
            for name in ("period", "skinType", "noLoad")
            for q, t in [one(db, name, "defaultCfgBoard")]
        )
    )
    q_en, t_en = one(dt, "enabled", "defaultCfgTriangle")
    q_sh, t_sh = one(dt, "shift", "defaultCfgTriangle")
    q_of, t_of = one(dt, "cdcOffset", "defaultCfgTriangle")
    default_triangle = TriangleConfig(
        _bool(p, q_en, t_en, "enabled"),
        _field(p, q_sh, t_sh, "shift"),
        _field(p, q_of, t_of, "cdcOffset"),
        q_en.line,
    )
    boards: dict[int, BoardConfig] = {}
    for q in params:
        if q.group != "specialCfgBoards" or not q.name.startswith("boardSetCfg"):
            continue
        tok = q.text.split()
        if len(tok) != 6:
            raise IcubFileError(
                p,
                q.line,
                f"{q.name}: expected 6 fields (patch addrStart addrEnd period skinType "
                f"noLoad), got {len(tok)}",
            )
        _, a0, a1, period, skin_type, no_load = (
            _field(p, q, t, w)
            for t, w in zip(
                tok, ("patch", "addrStart", "addrEnd", "period", "skinType", "noLoad"), strict=True
            )
        )
        if a1 < a0:
            raise IcubFileError(p, q.line, f"{q.name}: addrEnd {a1} before addrStart {a0}")
        for a in range(a0, a1 + 1):
            boards[a] = BoardConfig(period, skin_type, no_load)
    triangles: dict[tuple[int, int], TriangleConfig] = {}
    names = ("patch", "addr", "first", "last", "enabled", "shift", "cdcOffset")
    for q in params:
        if q.group != "specialCfgTriangles" or not q.name.startswith("triangleSetCfg"):
            continue
        tok = q.text.split()
        if len(tok) != 7:
            raise IcubFileError(
                p,
                q.line,
                f"{q.name}: expected 7 fields ({' '.join(names)}), got {len(tok)}",
            )
        _, addr, first, last = (_int(p, q, t, w) for t, w in zip(tok[:4], names[:4], strict=True))
        if not (0 <= addr <= 15 and 0 <= first <= last <= 15):
            raise IcubFileError(
                p, q.line, f"{q.name}: address {addr} or triangles {first}..{last} outside 0..15"
            )
        cfg = TriangleConfig(
            _bool(p, q, tok[4], "enabled"), _field(p, q, tok[5], "shift"),
            _field(p, q, tok[6], "cdcOffset"), q.line,
        )  # fmt: skip
        for t in range(first, last + 1):
            triangles[(addr, t)] = cfg
    return SkinSpec(p, default_board, default_triangle, boards, triangles)


def read_can_addresses(path: str | Path) -> tuple[int, ...]:
    """Board addresses of a ``*-skin.xml`` (embObjSkin) in port order: patch 2 first, then
    patch 1 (icub-main embObjSkin.cpp)."""
    p = str(path)
    group = _group(p, _params(p), "patches", True)
    out: list[int] = []
    for name in ("skinCanAddrsPatch2", "skinCanAddrsPatch1"):
        if name in group:
            q = group[name]
            for t in q.text.split():
                a = _ranged(p, q, t, "address", 0, 15)
                if a in out:  # (a board answers once on its bus: two slots cannot share it)
                    raise IcubFileError(p, q.line, f"{name}: CAN address {a} listed twice")
                out.append(a)
    if not out:
        raise IcubFileError(p, None, "group patches: no skinCanAddrsPatch1/2 parameter")
    return tuple(out)


def read_wrapper_ports(path: str | Path) -> dict[str, tuple[int, int]]:
    """Port name → (first, last) index into the device vector of a ``*-skin_wrapper.xml``."""
    p = str(path)
    out: dict[str, tuple[int, int]] = {}
    lines: dict[str, int] = {}
    for q in _params(p):
        if q.group != "ports":
            continue
        if q.name in lines:
            raise IcubFileError(
                p, q.line, f"port {q.name} defined twice (also at line {lines[q.name]})"
            )
        lines[q.name] = q.line
        tok = q.text.split()
        if len(tok) != 4:
            raise IcubFileError(
                p, q.line, f"port {q.name}: expected 4 fields (first last 0 size-1), got {tok}"
            )
        first, last = (_int(p, q, t, w) for t, w in zip(tok[:2], ("first", "last"), strict=True))
        out[q.name] = (first, last)
    if not out:
        raise IcubFileError(p, None, 'no <paramlist name="ports"> elements: not a skin wrapper')
    return out


def part_addresses(skin_xml: str | Path, wrapper_xml: str | Path, port: str) -> tuple[int, ...]:
    """CAN addresses of one part's boards in slot order (slot // 16 → address), from the
    robot's skin and wrapper files: the port's slice of the device vector, 192 values a board.
    """
    addrs = read_can_addresses(skin_xml)
    ports = read_wrapper_ports(wrapper_xml)
    if port not in ports:
        raise IcubFileError(
            str(wrapper_xml), None, f"no port named {port!r} (have: {', '.join(sorted(ports))})"
        )
    first, last = ports[port]
    if first % 192 or (last + 1) % 192 or last < first:
        raise IcubFileError(
            str(wrapper_xml), None, f"port {port}: range {first}..{last} is not whole boards"
        )
    b0, b1 = first // 192, (last + 1) // 192
    if b1 > len(addrs):
        raise IcubFileError(
            str(wrapper_xml),
            None,
            f"port {port}: boards {b0}..{b1 - 1} but {skin_xml} lists {len(addrs)} boards",
        )
    return addrs[b0:b1]
