"""Patch layouts: the YAML schema, loading and validation (the records they become are
:mod:`tactile_contact.model.layout_spec`, re-exported here).

A layout file holds one or more *patches*. A patch is a rigid piece of skin with its own frame:
a set of modules (type, CAN address, placement), one elastomer, one sensor calibration, the
reconstruction grids, the elastic model and the solver options. Everything the offline tool
needs to build a matrix bundle comes from here. All lengths are metres, moduli pascals,
capacitances farads (docs/layout.md lists every key with unit and default).

Validation errors are :class:`LayoutError` (a ``ValueError``) whose message names the file,
the key path and the problem, e.g.
``config/x.yaml: patches[0].modules[3].type: unknown module type 'foo' (known: ...)``.
"""

from __future__ import annotations

import contextlib
import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from tactile_contact.model.layout_spec import (  # the records; their old home re-exports them
    MASKS,
    MIN_TAXEL_SEPARATION,
    MODELS,
    PARAMETER_RULES,
    REGULARISERS,
    SCHEMA_VERSION,
    SOLVER_METHODS,
    Elastomer,
    GridSpec,
    Layout,
    LayoutError,
    ModelSpec,
    ModuleSpec,
    PatchLayout,
    SensorSpec,
    SolverSpec,
)
from tactile_contact.model.modules import MODULE_TYPES
from tactile_contact.model.surface import SHAPES, Surface

# --------------------------------------------------------------------------------------------
# Parsing. Each helper receives the error prefix ``where`` ("file: key.path") so that messages
# name exactly the offending entry.


def _as_float(v: Any) -> float | None:
    """``v`` as a float if it is a number or a numeric string, else None (bools are not)."""
    if isinstance(v, str):
        try:
            return float(v)
        except ValueError:
            return None
    if isinstance(v, bool) or not isinstance(v, int | float):
        return None
    return float(v)


class _Ctx:
    def __init__(self, source: str) -> None:
        self.source = source

    def err(self, path: str, msg: str) -> LayoutError:
        return LayoutError(f"{self.source}: {path}: {msg}" if path else f"{self.source}: {msg}")

    def mapping(self, value: Any, path: str, allowed: tuple[str, ...]) -> dict[str, Any]:
        if value is None:
            return {}
        if not isinstance(value, dict):
            raise self.err(path, f"expected a mapping, got {type(value).__name__}")
        unknown = [k for k in value if k not in allowed]
        if unknown:
            raise self.err(
                f"{path}.{unknown[0]}" if path else str(unknown[0]),
                f"unknown key (allowed: {', '.join(allowed)})",
            )
        return value

    def numbers(self, v: Any, path: str, n: int, what: str) -> tuple[float, ...]:
        """A list of ``n`` finite numbers (numeric strings as :meth:`number` takes them:
        PyYAML reads ``5e-2`` as a string)."""
        if isinstance(v, list | tuple) and len(v) == n:
            out = [_as_float(x) for x in v]
            if all(x is not None and math.isfinite(x) for x in out):
                return tuple(float(x) for x in out)  # type: ignore[arg-type]
        raise self.err(path, f"expected {what}, got {v!r}")

    def number(
        self,
        d: dict[str, Any],
        key: str,
        path: str,
        default: Any,
        *,
        lo: float | None = None,
        hi: float | None = None,
        lo_open: bool = False,
        hi_open: bool = False,
        integer: bool = False,
        optional: bool = False,
        unit: str = "",
    ) -> Any:
        p = f"{path}.{key}"
        if key not in d or d[key] is None:
            if default is _REQUIRED:
                raise self.err(p, "missing required key")
            return default
        v = d[key]
        if isinstance(v, str) and not integer:
            # PyYAML (YAML 1.1) reads 2.1e5 as a string: accept what float() accepts.
            with contextlib.suppress(ValueError):
                v = float(v)
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise self.err(p, f"expected a number, got {v!r}")
        if integer and (not isinstance(v, int)):
            raise self.err(p, f"expected an integer, got {v!r}")
        if not math.isfinite(v):
            raise self.err(p, f"must be finite, got {v!r}")
        if lo is not None and (v < lo or (lo_open and v == lo)):
            raise self.err(p, f"must be {'>' if lo_open else '>='} {lo}, got {v!r}")
        if hi is not None and (v > hi or (hi_open and v == hi)):
            text = f"must be {'<' if hi_open else '<='} {hi}" + (f" {unit}" if unit else "")
            if unit == "m" and (lo is None or v * 1e-3 > lo) and v * 1e-3 <= hi:
                # (the likeliest slip: a length written in millimetres)
                text += f", got {v!r}: millimetres given? {v:g} mm is {v * 1e-3:g} m"
                raise self.err(p, text + " (lengths are in metres)")
            raise self.err(p, f"{text}, got {v!r}")
        return int(v) if integer else float(v)

    def choice(
        self, d: dict[str, Any], key: str, path: str, default: str, options: tuple[str, ...]
    ) -> str:
        v = d.get(key, default)
        if not isinstance(v, str) or v not in options:  # (a list is unhashable: TypeError)
            raise self.err(f"{path}.{key}", f"unknown value {v!r} (known: {', '.join(options)})")
        return v


_REQUIRED = object()


#: Farthest a module may sit from its patch's origin [m]: a patch is one piece of skin on one
#: link (the robot's largest, an upper leg, spans ≈ 0.2 m).
MAX_MODULE_DISTANCE_M = 2.0
#: Widest a patch's taxels may spread [m] (an iCub upper leg's patch spans ≈ 0.2 m): its
#: build's grid covers their bounding box (1.4 m at 1 mm cells asked numpy for 6 GiB).
MAX_PATCH_SPAN_M = 0.5
#: A patch name: it is a token of the patch's ROS topic names (``<patch>/contact``), which
#: take ASCII letters, digits and '_' and no leading digit (rclpy refused ``left-arm`` only
#: at the bringup, after the build had accepted it).
PATCH_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*")


def _parse_module(c: _Ctx, raw: Any, path: str) -> ModuleSpec:
    d = c.mapping(
        raw,
        path,
        ("type", "board", "triangle", "position", "rotation_deg", "mirrored", "disabled_channels"),
    )
    if "type" not in d:
        raise c.err(f"{path}.type", "missing required key")
    if not isinstance(d["type"], str) or d["type"] not in MODULE_TYPES:
        known = ", ".join(sorted(MODULE_TYPES))
        raise c.err(f"{path}.type", f"unknown module type {d['type']!r} (known: {known})")
    board = c.number(d, "board", path, _REQUIRED, lo=0, hi=15, integer=True)
    tri = c.number(d, "triangle", path, _REQUIRED, lo=0, hi=15, integer=True)
    pos = c.numbers(d.get("position"), f"{path}.position", 2, "[x, y] in metres")
    if math.hypot(*pos) > MAX_MODULE_DISTANCE_M:
        # (a layout in millimetres loaded, then its build asked numpy for 24 GiB of grid)
        raise c.err(
            f"{path}.position",
            f"{math.hypot(*pos):.4g} m from the patch origin, more than "
            f"{MAX_MODULE_DISTANCE_M:g} m: expected metres (millimetres given?)",
        )
    rot = c.number(d, "rotation_deg", path, 0.0)
    mirrored = d.get("mirrored", False)
    if not isinstance(mirrored, bool):
        raise c.err(f"{path}.mirrored", f"expected true or false, got {mirrored!r}")
    dis = d.get("disabled_channels", []) or []
    nch = len(MODULE_TYPES[d["type"]].taxel)
    if not isinstance(dis, list) or not all(
        isinstance(v, int) and not isinstance(v, bool) and 0 <= v < nch for v in dis
    ):
        raise c.err(
            f"{path}.disabled_channels", f"expected a list of channels 0..{nch - 1}, got {dis!r}"
        )
    return ModuleSpec(
        d["type"],
        board,
        tri,
        (float(pos[0]), float(pos[1])),
        rot,
        mirrored,
        tuple(sorted(set(dis))),
    )


def _parse_patch(c: _Ctx, raw: Any, path: str) -> PatchLayout:
    d = c.mapping(
        raw,
        path,
        (
            "name",
            "frame_id",
            "modules",
            "elastomer",
            "sensor",
            "grid",
            "model",
            "solver",
            "surface",
            "bus",
        ),
    )
    name = d.get("name")
    if not isinstance(name, str) or not PATCH_NAME.fullmatch(name):
        quote = " (a string: quote it)" if isinstance(name, int | float) else ""
        raise c.err(
            f"{path}.name",
            "expected a name of ASCII letters, digits and '_' starting with a letter (it names "
            f"the patch's ROS topics and its bundle folder), got {name!r}{quote}",
        )
    frame = d.get("frame_id", name)
    _check_frame_id(c, frame, f"{path}.frame_id")
    mods = d.get("modules")
    if not isinstance(mods, list) or not mods:
        raise c.err(f"{path}.modules", "expected a non-empty list of modules")
    modules = tuple(_parse_module(c, m, f"{path}.modules[{i}]") for i, m in enumerate(mods))

    e = c.mapping(d.get("elastomer"), f"{path}.elastomer", ("thickness", "young", "poisson"))
    ep = f"{path}.elastomer"
    mod = c.mapping(
        d.get("model"),
        f"{path}.model",
        ("kind", "psi", "taxel_average", "footprint_radius", "gain", "layer_scale"),
    )
    kind = c.choice(mod, "kind", f"{path}.model", "love", MODELS)
    elast = Elastomer(
        thickness=c.number(e, "thickness", ep, 2.0e-3, lo=0.0, lo_open=True, hi=0.1, unit="m"),
        young=_young(c, e, ep),
        # ν = 0.5 (incompressible, Ecoflex) is fine for both models: every kernel stays finite.
        # Beyond 0.5 the material would be unstable; ν ≤ −1 likewise.
        poisson=c.number(e, "poisson", ep, 0.5, lo=-1.0, lo_open=True, hi=0.5),
    )
    psi: str | float = mod.get("psi", "exact")
    if psi != "exact" and _as_float(psi) is not None:
        psi = _as_float(psi)  # type: ignore[assignment]
    if kind == "love" and "psi" in mod:
        # Silently ignoring it would let a user believe the Ψ they set shapes the matrices.
        raise c.err(f"{path}.model.psi", "only the boussinesq model has a Ψ (kind is love)")
    if kind == "boussinesq" and not (
        psi == "exact"
        or (isinstance(psi, (int, float)) and not isinstance(psi, bool) and 0 < psi < 10)
    ):
        raise c.err(f"{path}.model.psi", f"expected 'exact' or a positive number, got {psi!r}")
    tav = mod.get("taxel_average", True)
    if not isinstance(tav, bool):
        raise c.err(f"{path}.model.taxel_average", f"expected true or false, got {tav!r}")
    mp = f"{path}.model"
    model = ModelSpec(
        kind,
        psi if isinstance(psi, str) else float(psi),
        tav,
        c.number(mod, "footprint_radius", mp, None, lo=0.0, hi=0.02, unit="m"),
        c.number(mod, "gain", mp, 1.0, lo=0.05, hi=20.0),
        c.number(mod, "layer_scale", mp, 1.0, lo=0.25, hi=4.0),
    )

    s = c.mapping(
        d.get("sensor"),
        f"{path}.sensor",
        ("epsilon_r", "taxel_radius", "area", "farad_per_count", "no_load", "shift", "cdc_offset"),
    )
    sp = f"{path}.sensor"
    if "taxel_radius" in s and "area" in s:
        raise c.err(f"{sp}.area", "give either taxel_radius or area, not both")
    if "area" in s:
        radius = math.sqrt(c.number(s, "area", sp, 0.0, lo=0.0, lo_open=True) / math.pi)
    else:
        radius = c.number(s, "taxel_radius", sp, 2.0e-3, lo=0.0, lo_open=True, hi=0.02, unit="m")
    sensor = SensorSpec(
        epsilon_r=c.number(s, "epsilon_r", sp, 4.37, lo=1.0),
        taxel_radius=radius,
        farad_per_count=c.number(s, "farad_per_count", sp, 0.32e-15, lo=0.0, lo_open=True),
        no_load=c.number(s, "no_load", sp, 240, lo=1, hi=255, integer=True),
        shift=c.number(s, "shift", sp, 2, lo=0, hi=15, integer=True),
        cdc_offset=c.number(s, "cdc_offset", sp, None, lo=0, hi=0xFFFF, integer=True),
    )

    g = c.mapping(
        d.get("grid"),
        f"{path}.grid",
        ("traction_cell", "deflection_cell", "margin", "mask", "mask_distance"),
    )
    gp = f"{path}.grid"
    grid = GridSpec(
        traction_cell=c.number(g, "traction_cell", gp, 2.0e-3, lo=1e-4, hi=0.05, unit="m"),
        deflection_cell=c.number(g, "deflection_cell", gp, 1.0e-3, lo=1e-4, hi=0.05, unit="m"),
        margin=c.number(g, "margin", gp, 3.0e-3, lo=0.0, hi=0.1, unit="m"),
        mask=c.choice(g, "mask", gp, "taxels", MASKS),
        mask_distance=c.number(
            g, "mask_distance", gp, 3.5e-3, lo=0.0, lo_open=True, hi=0.1, unit="m"
        ),
    )

    so = c.mapping(d.get("solver"), f"{path}.solver", tuple(SolverSpec.__dataclass_fields__))
    sop = f"{path}.solver"
    solver = SolverSpec(
        method=c.choice(so, "method", sop, "nnls_tikhonov", SOLVER_METHODS),
        regulariser=c.choice(so, "regulariser", sop, "identity", REGULARISERS),
        tikhonov=_number_or_rule(c, so, "tikhonov", sop, 0.1, lo=0.0, hi=10.0),
        rcond=c.number(so, "rcond", sop, 1e-3, lo=0.0, lo_open=True, hi=1.0),
        tsvd_rank=_number_or_rule(c, so, "tsvd_rank", sop, "discrepancy", lo=1, integer=True),
        noise=c.number(so, "noise", sop, 6.0e-6, lo=0.0, hi=1e-3, unit="m"),
        contact_threshold=c.number(so, "contact_threshold", sop, 1.1e-5, lo=0.0, hi=1e-3, unit="m"),
        nnls_method=c.choice(so, "nnls_method", sop, "bpp", ("bpp", "fista")),
        support_radius=c.number(
            so, "support_radius", sop, 4.0e-3, lo=0.0, lo_open=True, hi=0.1, unit="m"
        ),
        seed_fraction=c.number(so, "seed_fraction", sop, 0.3, lo=0.0, hi=1.0),
        area_rel_threshold=c.number(
            so, "area_rel_threshold", sop, 0.1, lo=0.0, hi=1.0, hi_open=True
        ),
        area_min_pressure=c.number(so, "area_min_pressure", sop, 100.0, lo=0.0),
        refine=c.choice(so, "refine", sop, "round", ("round", "none")),
        max_contacts=c.number(so, "max_contacts", sop, 3, lo=1, hi=8, integer=True),
    )
    surface = _parse_surface(c, d.get("surface"), f"{path}.surface")
    bus = d.get("bus", "")
    if not isinstance(bus, str) or not all(
        ch.isascii() and (ch.isalnum() or ch in "_-") for ch in bus
    ):
        quote = " (a string: quote it)" if isinstance(bus, int | float) else ""
        raise c.err(
            f"{path}.bus",
            f"expected a bus name of ASCII letters, digits, '_' or '-', got {bus!r}{quote}",
        )
    patch = PatchLayout(str(name), frame, modules, elast, sensor, grid, model, solver, surface, bus)
    _check_patch(c, patch, path)
    return patch


#: Young's moduli [Pa] a skin's elastomer has (silicones and foams: ≈ 10 kPa to 100 MPa);
#: outside, a unit was mistaken (0.21 for 0.21 MPa read 1e-6 of every force).
YOUNG_RANGE_PA = (1.0e3, 1.0e9)


def _young(c: _Ctx, e: dict[str, Any], path: str) -> float:
    """The elastomer's Young's modulus [Pa], refused outside YOUNG_RANGE_PA naming the unit."""
    v = float(c.number(e, "young", path, 2.1e5, lo=0.0, lo_open=True))
    lo, hi = YOUNG_RANGE_PA
    if v < lo:
        raise c.err(
            f"{path}.young",
            f"{v:g} Pa is softer than any skin elastomer (>= {lo:g} Pa): expected pascals "
            f"(MPa given? {v:g} MPa is {v * 1e6:g} Pa)",
        )
    if v > hi:
        raise c.err(f"{path}.young", f"{v:g} Pa is stiffer than any skin elastomer (<= {hi:g} Pa)")
    return v


def _check_frame_id(c: _Ctx, frame: Any, path: str) -> None:
    """A tf2 frame id: a non-empty string without a leading '/' (tf2 refuses it) or white
    space (rviz and URDF tools split on it)."""
    if not isinstance(frame, str) or not frame or frame.startswith("/"):
        raise c.err(path, f"expected a tf2 frame name (not empty, no leading '/'), got {frame!r}")
    if any(ch.isspace() for ch in frame):
        raise c.err(path, f"expected a tf2 frame name without white space, got {frame!r}")


def _parse_surface(c: _Ctx, raw: Any, path: str) -> Surface | None:
    """The optional ``surface`` of a patch (docs/layout.md)."""
    if raw is None:
        return None
    d = c.mapping(raw, path, ("frame_id", "shape", "origin", "orientation", "radius"))
    frame = d.get("frame_id")
    _check_frame_id(c, frame, f"{path}.frame_id")
    if "shape" not in d:
        raise c.err(f"{path}.shape", f"missing required key ({' or '.join(SHAPES)})")
    shape = c.choice(d, "shape", path, "", SHAPES)

    def vector(key: str, n: int, what: str) -> tuple[float, ...]:
        return c.numbers(d.get(key), f"{path}.{key}", n, what)

    origin = vector("origin", 3, "[x, y, z] in metres")
    quat = vector("orientation", 4, "a unit quaternion [x, y, z, w]")
    norm = math.sqrt(sum(x * x for x in quat))
    if abs(norm - 1.0) > 1e-3:
        raise c.err(f"{path}.orientation", f"not a unit quaternion (norm {norm:.6g})")
    radius = None
    if shape == "cylinder":
        radius = c.number(d, "radius", path, _REQUIRED, lo=0.0, lo_open=True, hi=10.0)
    elif "radius" in d:
        raise c.err(f"{path}.radius", "only a cylinder has a radius (shape is plane)")
    quat = tuple(x / norm for x in quat)
    return Surface(frame, shape, origin, quat, radius)  # type: ignore[arg-type]


def _check_patch(c: _Ctx, patch: PatchLayout, path: str) -> None:
    seen: dict[tuple[int, int], int] = {}
    for i, m in enumerate(patch.modules):
        key = (m.board, m.triangle)
        if key in seen:
            raise c.err(
                f"{path}.modules[{i}]",
                f"duplicate CAN address board {m.board} triangle "
                f"{m.triangle} (also modules[{seen[key]}])",
            )
        seen[key] = i
    xy = patch.taxel_xy()
    if len(xy) == 0:
        raise c.err(f"{path}.modules", "no valid taxel left (all channels disabled)")
    owner = [
        i
        for i, m in enumerate(patch.modules)
        for ch in range(12)
        if m.module_type.taxel[ch] and ch not in m.disabled_channels
    ]
    d2 = ((xy[:, None, :] - xy[None, :, :]) ** 2).sum(-1)
    np.fill_diagonal(d2, np.inf)
    i, j = np.unravel_index(int(np.argmin(d2)), d2.shape)
    # Two electrodes cannot share skin: their discs must not overlap.
    limit = max(MIN_TAXEL_SEPARATION, 2.0 * patch.sensor.taxel_radius)
    if d2[i, j] < limit**2:
        raise c.err(
            f"{path}.modules[{owner[j]}]",
            f"overlapping taxels: a taxel at "
            f"({xy[j, 0]:.4f}, {xy[j, 1]:.4f}) m is {math.sqrt(d2[i, j]) * 1e3:.2f} mm from "
            f"one of modules[{owner[i]}] (their electrodes of radius "
            f"{patch.sensor.taxel_radius * 1e3:g} mm overlap below {limit * 1e3:g} mm)",
        )
    span = float(np.sqrt(d2[np.isfinite(d2)].max())) if len(xy) > 1 else 0.0
    if span > MAX_PATCH_SPAN_M:
        i, j = np.unravel_index(int(np.argmax(np.where(np.isfinite(d2), d2, -1.0))), d2.shape)
        raise c.err(
            f"{path}.modules",
            f"the taxels span {span:.3g} m (modules[{owner[i]}] to modules[{owner[j]}]), more "
            f"than {MAX_PATCH_SPAN_M:g} m: a patch is one piece of skin on one link, its "
            "positions in its own frame (positions in a robot frame? a second patch?)",
        )


def _number_or_rule(c: Any, d: dict[str, Any], key: str, path: str, default: Any, **kw: Any):
    """A number as ``c.number`` checks it, or the name of a parameter rule (PARAMETER_RULES);
    ``all`` is None (for ``tsvd_rank``: no truncation)."""
    v = d.get(key)
    if v in PARAMETER_RULES:
        return v
    if key == "tsvd_rank" and v == "all":
        return None
    try:
        return c.number(d, key, path, default, **kw)
    except LayoutError:
        if isinstance(v, str):
            known = ", ".join(PARAMETER_RULES + (("all",) if key == "tsvd_rank" else ()))
            raise c.err(
                f"{path}.{key}", f"unknown rule {v!r} (known: {known}, or a number)"
            ) from None
        raise


def parse_layout(data: Any, source: str = "<memory>") -> Layout:
    """Validate plain data (as loaded from YAML) and return a :class:`Layout`."""
    c = _Ctx(source)
    d = c.mapping(data, "", ("schema_version", "patches"))
    ver = d.get("schema_version", SCHEMA_VERSION)
    if ver != SCHEMA_VERSION:
        raise c.err(
            "schema_version", f"unsupported version {ver!r} (this library reads {SCHEMA_VERSION})"
        )
    raw = d.get("patches")
    if not isinstance(raw, list) or not raw:
        raise c.err("patches", "expected a non-empty list of patches")
    patches = tuple(_parse_patch(c, p, f"patches[{i}]") for i, p in enumerate(raw))
    names: dict[str, int] = {}
    frames: dict[str, int] = {}
    addr: dict[tuple[str, int, int], str] = {}
    for i, p in enumerate(patches):
        if p.name in names:
            raise c.err(
                f"patches[{i}].name",
                f"duplicate patch name {p.name!r} (also patches[{names[p.name]}])",
            )
        names[p.name] = i
        if p.frame_id in frames:
            # Two patches may share a frame (one sheet split over two buses), side by side;
            # taxels of both at one place are a copy left in the first's frame, drawn on it.
            j = frames[p.frame_id]
            a, b = patches[j].taxel_xy(), p.taxel_xy()
            gap = float(np.sqrt(((a[:, None, :] - b[None, :, :]) ** 2).sum(-1).min()))
            limit = max(
                MIN_TAXEL_SEPARATION, p.sensor.taxel_radius + patches[j].sensor.taxel_radius
            )
            if gap < limit:
                raise c.err(
                    f"patches[{i}].frame_id",
                    f"frame {p.frame_id!r} is also patches[{j}]'s, and their taxels overlap "
                    f"({gap * 1e3:.2f} mm apart): a copied patch? give it a frame of its own",
                )
        frames.setdefault(p.frame_id, i)
        for k, m in enumerate(p.modules):
            key = (p.bus, m.board, m.triangle)  # addresses are unique on one bus
            if key in addr:
                on = f" on bus {p.bus!r}" if p.bus else ""
                raise c.err(
                    f"patches[{i}].modules[{k}]",
                    f"duplicate CAN address board {m.board} "
                    f"triangle {m.triangle}{on} (also in patch {addr[key]!r})",
                )
            addr[key] = p.name
    return Layout(patches, source)


def load_layout(path: str | Path) -> Layout:
    """Read and validate a layout YAML file; raises :class:`LayoutError`."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise LayoutError(f"{p}: cannot read: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        line = p.read_bytes()[: exc.start].count(b"\n") + 1
        raise LayoutError(
            f"{p}:{line}: not UTF-8 text (byte {exc.object[exc.start]:#04x}); save it as UTF-8"
        ) from None
    try:
        data = yaml.load(text, Loader=_UniqueKeyLoader)  # (a SafeLoader)
    except yaml.YAMLError as exc:
        raise LayoutError(f"{p}: invalid YAML: {exc}".replace("\n", " ")) from None
    return parse_layout(data, str(p))


class _UniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's safe loader, but a key given twice in one mapping is an error (PyYAML keeps
    the last silently: a second ``modules:`` turned a patch of 6 modules into 1)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        seen: dict[object, int] = {}
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                continue  # `<<: *defaults`: the base class merges (keys given here override)
            key = self.construct_object(key_node, deep=deep)
            try:
                first = seen.get(key)
            except TypeError:
                continue  # (an unhashable key: the base class says so)
            if first is not None:
                raise yaml.constructor.ConstructorError(
                    None,
                    None,
                    f"key {key!r} given twice in one mapping (first at line {first})",
                    key_node.start_mark,
                )
            seen[key] = key_node.start_mark.line + 1
        return super().construct_mapping(node, deep=deep)
