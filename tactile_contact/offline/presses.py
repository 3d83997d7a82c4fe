"""Presses of known force and position: the file ``tactile-contact-calibrate`` reads, and the
``tactile-contact-presses`` command that makes it from a recorded session.

PRESSES.npz: ``deflection`` (N, K) compressions [m] in the bundle's taxel order (the quantity
``Reconstructor.solve_deflection`` takes) or ``delta_c`` (N, K) ΔC in CDC counts (converted
with the layout's sensor model); ``force`` (N,) [N]; ``position`` (N, 2) [m], patch frame;
optionally ``indenter`` (N,) strings and ``valid`` (N, K) bool.

:func:`load_presses` checks such a file for a patch (every problem one
:class:`CalibrationError` naming the file and the key); :func:`presses_from_bag` pairs a bag's
``<patch>/contact_truth`` messages with its ``<patch>/taxels`` frames. No ROS import (the bag is
read with the ``rosbags`` library).
"""

from __future__ import annotations

import argparse
import math
import re
import sys
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tactile_contact.model.indenters import FlatPunch, HertzSphere, Indenter
from tactile_contact.model.layout import LayoutError, PatchLayout, load_layout

#: Indenters a press may name (the paper's set; the simulator and bench use the same).
INDENTERS: dict[str, Indenter] = {
    "sphere 12 mm": HertzSphere(6e-3),
    "sphere 6 mm": HertzSphere(3e-3),
    "cylinder 12 mm": FlatPunch(6e-3),
    "cylinder 3 mm": FlatPunch(1.5e-3),
}
#: Fewest presses accepted: three parameters, and a press informs mostly its own taxels.
MIN_PRESSES = 8


class CalibrationError(ValueError):
    """A presses file or calibration that cannot be used; the message names the file/key."""


@dataclass(frozen=True)
class Presses:
    """Validated presses: deflection (N, K) [m], force (N,) [N], position (N, 2) [m],
    indenter (N,) names or None, valid (N, K) bool."""

    deflection: NDArray[np.float64]
    force: NDArray[np.float64]
    position: NDArray[np.float64]
    indenter: tuple[str, ...] | None
    valid: NDArray[np.bool_]


def indenter_named(name: str) -> Indenter:
    """The indenter a press names: a key of INDENTERS, or "hertz:R" / "punch:a" (R, a in mm)."""
    key = str(name).strip().lower()
    if key in INDENTERS:
        return INDENTERS[key]
    m = re.fullmatch(r"(hertz|sphere|punch|cylinder)\s*:\s*([0-9]*\.?[0-9]+(?:e[-+]?[0-9]+)?)", key)
    if m:
        size = float(m.group(2)) * 1e-3
        if not (math.isfinite(size) and 0.0 < size <= 1.0):
            raise CalibrationError(f"indenter {name!r}: its radius must be > 0 and at most 1000 mm")
        return HertzSphere(size) if m.group(1) in ("hertz", "sphere") else FlatPunch(size)
    known = ", ".join(sorted(INDENTERS))
    raise CalibrationError(
        f"unknown indenter {name!r}: expected one of {known}, or hertz:R / punch:a "
        "(the sphere's or the punch's radius R, a in mm)"
    )


_NPZ_HINT = (
    "write one with numpy.savez(PATH, force=…, position=…, deflection=…) "
    "(or tactile-contact-presses from a recorded session)"
)


def _what_file(path: Path) -> str:
    """A few words on what a file that is not a .npz archive holds."""
    with path.open("rb") as f:
        head = f.read(512)
    if head.startswith(b"\x93NUMPY"):
        return "a single .npy array"
    if not head:
        return "an empty file"
    try:
        head.decode("utf-8")
    except UnicodeDecodeError:
        return "binary data"
    return "text: " + repr(head.splitlines()[0][:40].decode("utf-8", "replace"))


def _same_presses(path: Path, rows: dict[str, int]) -> None:
    """One entry per press in every array: else the one that differs from the rest is named."""
    if len(set(rows.values())) == 1:
        return
    counts = list(rows.values())
    odd = [key for key, n in rows.items() if counts.count(n) == 1]
    key = odd[0] if len(odd) == 1 else next(iter(rows))
    others = " and ".join(f"{k!r} {n}" for k, n in rows.items() if k != key)
    raise CalibrationError(
        f"{path}: {key!r} has {rows[key]} presses, {others}: one entry per press in each"
    )


def load_presses(path: str | Path, patch: PatchLayout) -> Presses:
    """Read and check PRESSES.npz for ``patch`` (errors name the file and the key)."""
    p = Path(path)
    if not p.is_file():
        raise CalibrationError(f"{p}: no such file")
    if not zipfile.is_zipfile(p):  # (np.load would try it as a pickle and say so)
        raise CalibrationError(f"{p}: not a readable .npz file ({_what_file(p)}); {_NPZ_HINT}")
    try:
        z = np.load(p, allow_pickle=False)
        data = {k: z[k] for k in z.files}
    except Exception as e:  # every unreadable file is one clear error
        raise CalibrationError(f"{p}: not a readable .npz file ({e})") from None
    k = len(patch.taxel_xy())

    def need(key: str) -> NDArray:
        if key not in data:
            raise CalibrationError(f"{p}: missing key {key!r} (keys: {sorted(data)})")
        return data[key]

    def numbers(key: str, raw: NDArray) -> NDArray[np.float64]:
        a = np.asarray(raw)
        if a.dtype.kind not in "biuf":  # (strings "1 N", complex, objects)
            first = a.flat[0] if a.size else None
            raise CalibrationError(
                f"{p}: {key!r} must hold numbers, got {a.dtype} values (first {first!r})"
            )
        return a.astype(np.float64)

    force = numbers("force", need("force"))
    if force.ndim != 1:
        raise CalibrationError(f"{p}: 'force' must have shape (N,), got {force.shape}")
    n = len(force)
    if "deflection" in data:
        src = "deflection"
    elif "delta_c" in data:
        src = "delta_c"
    else:
        raise CalibrationError(
            f"{p}: needs 'deflection' [m] or 'delta_c' [counts], (presses, taxels); "
            f"keys: {sorted(data)}"
        )
    d = numbers(src, data[src])
    if d.ndim != 2 or d.shape[1] != k:
        raise CalibrationError(
            f"{p}: {src!r} must have shape (presses, {k}): one reading per taxel of patch "
            f"{patch.name!r} in each row, got {d.shape}"
        )
    pos = numbers("position", need("position"))
    if pos.ndim != 2 or pos.shape[1] != 2:
        raise CalibrationError(f"{p}: 'position' must have shape (presses, 2) [m], got {pos.shape}")
    _same_presses(p, {"force": n, src: d.shape[0], "position": pos.shape[0]})
    if src == "delta_c":
        from tactile_contact.model.sensor import delta_c_to_compression, value_count_farad

        s = patch.sensor
        counts = d
        top_counts = float(np.nanmax(np.abs(counts))) if np.isfinite(counts).any() else 0.0
        if 0.0 < top_counts < 0.5:
            # (no press reads under half a count on every taxel: ΔC in farads reads ~1e-14)
            raise CalibrationError(
                f"{p}: 'delta_c' up to {top_counts:g}: expected CDC counts (ΔC of the 8-bit "
                "values × 2^shift), not farads"
            )
        dc = counts * value_count_farad(s.farad_per_count, s.shift)
        d = delta_c_to_compression(
            np.where(np.isfinite(dc), dc, 0.0), patch.elastomer.thickness, s.epsilon_r, s.area
        )
        d = np.where(np.isfinite(counts), d, np.nan)
    valid = np.ones((n, k), bool)
    if "valid" in data:
        valid = np.asarray(data["valid"], dtype=bool)
        if valid.shape != (n, k):
            raise CalibrationError(f"{p}: 'valid' must have shape ({n}, {k}), got {valid.shape}")
    for key, v in (("force", force), ("position", pos)):
        if not np.all(np.isfinite(v)):
            bad = np.argwhere(~np.isfinite(v))[0]
            raise CalibrationError(f"{p}: {key!r} holds NaN or inf (first at index {bad.tolist()})")
    if not np.any(np.isfinite(d) & valid):
        raise CalibrationError(f"{p}: {src!r} holds no finite reading")
    valid &= np.isfinite(d)
    d = np.where(valid, d, 0.0)
    if np.any(force <= 0):
        raise CalibrationError(f"{p}: 'force' must be > 0 N (press {int(np.argmin(force))})")
    if force.max() > 100.0:
        raise CalibrationError(
            f"{p}: 'force' up to {force.max():g} N: expected newtons (millinewtons given?)"
        )
    span = np.abs(patch.taxel_xy()).max() + 0.05
    if np.abs(pos).max() > span:
        raise CalibrationError(
            f"{p}: 'position' up to {np.abs(pos).max():g}: expected metres in the patch frame "
            "(millimetres given?)"
        )
    h = patch.elastomer.thickness
    top = float(np.abs(d).max())
    if top >= h:
        if src == "delta_c":
            hint = "expected CDC counts (ΔC of the 8-bit values × 2^shift)"
        else:  # a compression never reaches the layer's thickness: in mm it stays below h·1e3
            hint = "expected metres (" + ("millimetres" if top <= h * 1e3 else "micrometres")
            hint += " given?)"
        raise CalibrationError(
            f"{p}: {src!r} up to {top:g}, giving compressions not below the layer thickness "
            f"{h:g} m: {hint}"
        )
    if n < MIN_PRESSES:
        raise CalibrationError(f"{p}: {n} presses; at least {MIN_PRESSES} are needed")
    _check_readings(p, src, d, valid, pos, patch)
    names = None
    if "indenter" in data:
        raw = np.asarray(data["indenter"])
        if raw.shape != (n,):
            raise CalibrationError(f"{p}: 'indenter' must have shape ({n},), got {raw.shape}")
        if raw.dtype.kind == "S":  # (bytes written by another tool: names all the same)
            raw = np.char.decode(raw, "utf-8", "replace")
        names = tuple(str(x) for x in raw)
        for x in names:
            try:
                indenter_named(x)
            except CalibrationError as e:
                raise CalibrationError(f"{p}: 'indenter': {e}") from None
    return Presses(d, force, pos, names, valid)


#: Taxels within this distance [m] of a press's position read it (its sign test).
SIGN_REACH_M = 0.004
#: A press farther than this from every taxel [m] is read by none (a position in another
#: frame, a press beside the skin).
UNREAD_DISTANCE_M = 0.01


def _check_readings(
    p: Path, src: str, d: NDArray, valid: NDArray, pos: NDArray, patch: PatchLayout
) -> None:
    """Readings a fit cannot use, named: the sign convention reversed (compressions are
    positive: ΔC grows when pressed), a press beside the skin. (A press that reads almost
    nothing is kept: a light one between point taxels does; the report names it if the fit
    predicts more.)"""
    xy = patch.taxel_xy()
    dist = np.hypot(*(pos[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))  # (presses, K)
    far = dist.min(axis=1)
    beside = np.flatnonzero(far > UNREAD_DISTANCE_M)
    if beside.size:
        i = int(beside[0])
        raise CalibrationError(
            f"{p}: press(es) {beside.tolist()} lie more than {UNREAD_DISTANCE_M * 1e3:g} mm "
            f"from every taxel (press {i} at {pos[i].tolist()} m: {far[i] * 1e3:.1f} mm): "
            "positions in the patch frame, in metres?"
        )
    # Under the press: the reading of largest magnitude within SIGN_REACH_M of its position
    # (anywhere else, baseline offsets and the bulge ring around a light press read as much
    # as its peak: the shipped session's presses have their largest |reading| negative in 11
    # of 93).
    under = np.where((dist <= SIGN_REACH_M) & valid, d, 0.0)
    sign = np.sign(under[np.arange(len(d)), np.abs(under).argmax(axis=1)])
    if np.sum(sign < 0) > 2 * max(np.sum(sign > 0), 1):
        raise CalibrationError(
            f"{p}: {src!r}: {int(np.sum(sign < 0))} of {len(d)} presses read negative under "
            f"their position (the taxels within {SIGN_REACH_M * 1e3:g} mm), "
            f"{int(np.sum(sign > 0))} positive: compression is positive (ΔC grows when "
            "pressed); readings of the opposite sign convention?"
        )


def presses_from_bag(bag: Path, patch: PatchLayout, *, min_force: float = 0.05) -> dict:
    """PRESSES arrays from a recorded calibration session: every ``<patch>/contact_truth``
    message (the rig's force sensor and position, or the simulator's truth) with a force of
    at least ``min_force`` [N], paired with the ``<patch>/taxels`` frame of the same stamp.

    Errors (:class:`CalibrationError`) name the bag and what is missing.
    """
    from tactile_contact.canbus.baseline import STATUS_CONTACT
    from tactile_contact.model.sensor import delta_c_to_compression
    from tactile_contact.ros.bag import read_messages

    topics = (f"{patch.name}/taxels", f"{patch.name}/contact_truth")
    try:
        # Everything, then filtered: the bag's names may or may not carry the leading slash,
        # and asking for a topic a bag lacks is an error of its own.
        msgs = [m for m in read_messages(bag) if m[0].lstrip("/") in topics]
    except Exception as e:  # every unreadable bag is one clear error
        raise CalibrationError(f"{bag}: cannot read the bag ({e})") from None
    frames: dict[int, Any] = {}
    truths = []
    for topic, _, m in msgs:
        stamp = int(m.header.stamp.sec) * 1_000_000_000 + int(m.header.stamp.nanosec)
        if topic.lstrip("/") == topics[0]:
            frames[stamp] = m
        elif m.in_contact and m.total_force >= min_force:
            truths.append((stamp, m))
    for t, what in ((frames, "taxel frames"), (truths, "pressed contact_truth messages")):
        if not t:
            raise CalibrationError(f"{bag}: no {what} on {topics} (topics recorded?)")
    ids = patch.taxel_ids()
    s, h = patch.sensor, patch.elastomer.thickness
    deflection, force, position, names, valid = [], [], [], [], []
    for stamp, m in truths:
        f = frames.get(stamp)
        if f is None:
            continue
        where = {int(t): i for i, t in enumerate(f.taxel_ids)}
        idx = np.array([where.get(int(t), -1) for t in ids])
        dc = np.asarray(f.delta_c, dtype=np.float64)[np.maximum(idx, 0)]
        # Any flag but contact excludes a taxel; the contact flag marks the taxels pressed
        # (dropping them, as `== 0` did, left 82 of the shipped session's 93 presses without
        # the taxel under them).
        flags = np.asarray(f.status)[np.maximum(idx, 0)] & ~np.uint8(STATUS_CONTACT)
        ok = (idx >= 0) & np.isfinite(dc) & (flags == 0)
        d = delta_c_to_compression(np.where(ok, dc, 0.0), h, s.epsilon_r, s.area)
        deflection.append(np.where(ok, d, np.nan))
        valid.append(ok)
        force.append(float(m.total_force))
        position.append((m.center_of_pressure.x, m.center_of_pressure.y))
        names.append(_indenter_name(m, patch))
    if len(force) == 0:
        raise CalibrationError(f"{bag}: no contact_truth stamp matches a taxel frame's stamp")
    out = {
        "deflection": np.array(deflection),
        "force": np.array(force),
        "position": np.array(position),
        "valid": np.array(valid),
    }
    if all(n is not None for n in names):
        out["indenter"] = np.array(names)
    return out


def _indenter_name(msg: Any, patch: PatchLayout) -> str | None:
    """ "hertz:R" / "punch:a" [mm] from a truth message's single contact, else None."""
    if len(msg.contacts) != 1:
        return None
    c = msg.contacts[0]
    if c.profile == "punch":
        return f"punch:{c.radius * 1e3:.6g}"
    if c.profile == "hertz":
        from tactile_contact.model.indenters import effective_modulus

        e = patch.elastomer
        radius = 4.0 * effective_modulus(e.young, e.poisson) * c.radius**3 / (3.0 * c.force)
        return f"hertz:{radius * 1e3:.6g}"
    return None


def main_presses(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="tactile-contact-presses",
        description="Turn a recorded calibration session (a bag with <patch>/taxels and "
        "<patch>/contact_truth) into PRESSES.npz for tactile-contact-calibrate.",
    )
    ap.add_argument("bag", type=Path, help="rosbag2 folder (MCAP or sqlite3)")
    ap.add_argument("layout", type=Path, help="patch layout YAML")
    ap.add_argument("-o", "--out", type=Path, required=True, help="PRESSES.npz to write")
    ap.add_argument("--patch", help="patch (needed when the layout has several)")
    ap.add_argument("--min-force", type=float, default=0.05, help="least force kept [N]")
    args = ap.parse_args(argv)
    try:
        lay = load_layout(args.layout)
        if args.patch is None and len(lay.patches) != 1:
            names = ", ".join(p.name for p in lay.patches)
            raise CalibrationError(f"{args.layout}: several patches ({names}): pass --patch")
        patch = lay.patch(args.patch) if args.patch else lay.patches[0]
        arrays = presses_from_bag(args.bag, patch, min_force=args.min_force)
        # (numpy adds .npz to a name without it: say the file that is written)
        out = args.out if args.out.suffix == ".npz" else args.out.with_name(args.out.name + ".npz")
        np.savez(out, **arrays)
    except (CalibrationError, LayoutError, KeyError, OSError) as e:
        print(f"ERROR: {e}", file=sys.stderr)
        return 1
    print(f"{out}: {len(arrays['force'])} presses from {args.bag}")
    return 0


if __name__ == "__main__":
    sys.exit(main_presses())
