"""The independent truths: fine forward models with taxel responses of their own.

A reconstruction is never judged on readings made with its own forward model: the truth is
:class:`tactile_contact.model.forward.ForwardModel` on 0.25 mm cells (exact cell-averaged
Hertz / flat-punch pressure, Love kernel, the taxel's own footprint), here with a taxel
response other than the bundle's where the bench asks for one:

    point           the compression at the taxel centre
    2 mm electrode  the mean over a 2 mm disc (the layout's nominal response)
    3 mm electrode  the mean over a 3 mm disc
    gain 0.85/1.15  the 2 mm electrode's reading × 0.85 / × 1.15
    layer 0.9/1.1   the 2 mm electrode over a layer 10 % thinner / thicker

:class:`Truth` reproduces ForwardModel exactly (the same fine cells, centred on the contact, of
edge min(fine_cell, a/8); the same 8 × 24-point electrode quadrature; the Love kernel) but keeps
the kernel from the fine cells to the taxels: every force of a press that shares the cell size
(a flat punch at any force, a sphere at the forces whose contact radius is ≥ 8 fine cells)
reuses it, and the Jacobian of the readings in (x, y, force, indenter size) costs only cell
pressures on the same cells (central differences at fixed discretisation), for the Cramér–Rao
bound (:mod:`benchkit.stats`). The first press of each truth is checked against
``ForwardModel.compression``. Presses of the protocol are cached under out/bench-robust-cache
(first full run: ≈ 15 min of simulation on one core).
"""

from __future__ import annotations

import math
import zlib

import numpy as np
from numpy.typing import NDArray

from benchkit import ROOT
from benchkit.protocol import FORCES, INDENTERS, QUICK_FORCES, Patch, positions
from tactile_contact.inverse.reconstruction import Reconstructor
from tactile_contact.model.elastic import love_matrix
from tactile_contact.model.forward import ForwardModel
from tactile_contact.model.grids import disc_quadrature
from tactile_contact.model.indenters import Indenter

#: Parameters of the Jacobian's columns, in order.
PARAMS = ("x", "y", "force", "size")
#: Central-difference steps: centre [m], force and size (relative).
STEP_XY = 1.0e-5
STEP_REL = 1.0e-3
#: Points per kernel chunk (bounds the memory of the quadrature points × cells block).
CHUNK = 1_500_000
#: Fine cell edge of the truths [m].
FINE_CELL = 2.5e-4


def fine_model(recon: Reconstructor) -> ForwardModel:
    """The fine forward model of a bundle's own patch (its taxels, layer and footprint)."""
    p = recon.params
    return ForwardModel(
        recon.taxel_xy,
        p["thickness"],
        p["young"],
        p["poisson"],
        fine_cell=FINE_CELL,
        taxel_radius=p["taxel_radius"],
    )


class Truth:
    """A taxel response (point value or electrode mean) over an elastic layer; see module doc.

    Args:
        xy: (K, 2) taxel centres [m], bundle order.
        thickness, young, poisson: layer h [m], E [Pa], ν.
        taxel_radius: footprint the taxel averages the compression over [m] (0: point value).
        fine_cell: edge of the fine pressure cells [m] (as ForwardModel).
    """

    def __init__(
        self,
        xy: NDArray[np.float64],
        thickness: float,
        young: float,
        poisson: float,
        taxel_radius: float,
        fine_cell: float = FINE_CELL,
    ) -> None:
        self.xy = np.asarray(xy, dtype=np.float64)
        self.thickness, self.young, self.poisson = float(thickness), float(young), float(poisson)
        self.taxel_radius, self.fine_cell = float(taxel_radius), float(fine_cell)
        q, self._w = disc_quadrature(self.taxel_radius, n_r=8, n_theta=24)
        self._q = len(self._w)
        self._pts = (self.xy[:, None, :] + q[None, :, :]).reshape(-1, 2)
        self._checked = False

    def model(self) -> ForwardModel:
        """The ForwardModel this truth reproduces."""
        return ForwardModel(
            self.xy,
            self.thickness,
            self.young,
            self.poisson,
            fine_cell=self.fine_cell,
            taxel_radius=self.taxel_radius,
        )

    def cell(self, indenter: Indenter, force: float) -> float:
        """ForwardModel's fine cell edge [m] for this contact."""
        a = indenter.contact_radius(force, self.young, self.poisson)
        return min(self.fine_cell, a / 8.0)

    @staticmethod
    def _cells(reach: float, cell: float, center: NDArray) -> NDArray[np.float64]:
        """ForwardModel._cells' lattice (cells centred at ±(k + ½)·cell about the centre) over a
        disc of radius ``reach``: for reach ≥ a it holds every cell ForwardModel uses."""
        n = 2 * math.ceil(reach / cell)
        c1 = (np.arange(n) - n / 2 + 0.5) * cell
        xx, yy = np.meshgrid(c1, c1)
        dx = np.maximum(np.abs(xx) - cell / 2, 0)
        dy = np.maximum(np.abs(yy) - cell / 2, 0)
        keep = dx**2 + dy**2 < reach * reach
        return np.stack((xx[keep], yy[keep]), axis=-1) + center

    def _kernel(self, cells: NDArray, cell: float) -> NDArray[np.float64]:
        """(K, M) compression at the taxels [m] per unit pressure [Pa] on each fine cell."""
        k, q, m = len(self.xy), self._q, len(cells)
        out = np.empty((k, m))
        rows = max(1, CHUNK // max(m * q, 1))  # taxels per chunk
        hs = np.full(2, cell / 2)
        for s in range(0, k, rows):
            e = min(k, s + rows)
            g = love_matrix(
                self._pts[s * q : e * q], cells, hs, self.thickness, self.young, self.poisson
            )
            out[s:e] = self._w @ g.reshape(e - s, q, m)
        return out

    def presses(
        self, indenter: Indenter, forces: list[float], center: NDArray, jacobian: bool = True
    ) -> tuple[NDArray[np.float64], NDArray[np.float64] | None]:
        """Readings (len(forces), K) [m] of ``indenter`` at ``center`` [m] pressed with each
        force, and their Jacobians (len(forces), K, 4) in (x [m], y [m], force [N], size [m])
        (None without ``jacobian``)."""
        c = np.asarray(center, dtype=np.float64)
        make = type(indenter)
        size = float(indenter.radius)
        e, nu = self.young, self.poisson
        out = np.empty((len(forces), len(self.xy)))
        jac = np.empty((len(forces), len(self.xy), 4)) if jacobian else None
        groups: dict[float, list[int]] = {}
        for i, f in enumerate(forces):
            groups.setdefault(self.cell(indenter, f), []).append(i)
        for cell, idx in groups.items():
            a_max = max(indenter.contact_radius(forces[i], e, nu) for i in idx)
            # Room for the perturbed contacts (larger force or size, shifted centre).
            reach = a_max * (1.0 + 4.0 * STEP_REL) + 2.0 * STEP_XY + 2.0 * cell
            cells = self._cells(reach, cell, c)
            kern = self._kernel(cells, cell)
            hs = np.full(2, cell / 2)

            def reading(x, y, f, s, kern=kern, cells=cells, hs=hs):
                p = make(s).pressure_on_cells(cells, hs, f, (x, y), e, nu)
                return kern @ p

            for i in idx:
                f = float(forces[i])
                v0 = np.array([c[0], c[1], f, size])
                out[i] = reading(*v0)
                if jac is None:
                    continue
                steps = (STEP_XY, STEP_XY, STEP_REL * f, STEP_REL * size)
                for j, h in enumerate(steps):
                    dv = np.zeros(4)
                    dv[j] = h
                    jac[i, :, j] = (reading(*(v0 + dv)) - reading(*(v0 - dv))) / (2 * h)
        if not self._checked:
            ref = self.model().compression(indenter, float(forces[0]), c)
            err = np.abs(out[0] - ref).max() / max(np.abs(ref).max(), 1e-30)
            if err > 1e-9:
                raise RuntimeError(f"Truth differs from ForwardModel by {err:.2e} (relative)")
            self._checked = True
        return out, jac


# --- the taxel responses and their cached presses -------------------------------------------

CACHE = ROOT / "out" / "bench-robust-cache"
CACHE_VERSION = 1
#: name → (footprint radius [m], layer thickness scale, gain)
TRUTHS = {
    "point": (0.0, 1.0, 1.0),
    "2 mm electrode": (2e-3, 1.0, 1.0),
    "3 mm electrode": (3e-3, 1.0, 1.0),
    "gain 0.85": (2e-3, 1.0, 0.85),
    "gain 1.15": (2e-3, 1.0, 1.15),
    "layer 0.9": (2e-3, 0.9, 1.0),
    "layer 1.1": (2e-3, 1.1, 1.0),
}
SHORT = {
    "point": "pt",
    "2 mm electrode": "e2",
    "3 mm electrode": "e3",
    "gain 0.85": "g.85",
    "gain 1.15": "g1.15",
    "layer 0.9": "h.9",
    "layer 1.1": "h1.1",
}
QUICK_TRUTHS = ("point", "gain 1.15")
N_CAL, N_CAL_QUICK = 48, 24
CAL_MIN_DIST = 2e-3  # calibration places: at least this far from every test place [m]
CAL_ON_SKIN = 3e-3  # ... and at most this far from a taxel [m]


def truth(lay: Patch, name: str) -> Truth:
    """The truth ``name`` (a key of TRUTHS) on the patch; its gain is applied by the callers."""
    foot, scale, _ = TRUTHS[name]
    return Truth(lay.xy, lay.thickness * scale, lay.young, lay.poisson, foot)


def _tag(lay: Patch, name: str) -> str:
    foot, scale, _ = TRUTHS[name]
    key = repr((CACHE_VERSION, lay.xy.round(9).tolist(), lay.thickness, lay.young, lay.poisson))
    return f"r{foot * 1e3:g}_h{scale:g}_{zlib.crc32(key.encode()):08x}"


def test_presses(lay: Patch, name: str, quick: bool = False) -> dict[str, NDArray]:
    """The protocol's presses of truth ``name``: d (N, K) [m], J (N, K, 4), f (N,), c (N, 2),
    ind (N,) names, place (N,) kinds. Cached per indenter and place (all six forces)."""
    gain = TRUTHS[name][2]
    folder = CACHE / _tag(lay, name)
    folder.mkdir(parents=True, exist_ok=True)
    made = None
    places = positions(lay.xy, (4,) if quick else (4, 2), lay.ids)
    forces = QUICK_FORCES if quick else FORCES
    rows: dict[str, list] = {k: [] for k in ("d", "J", "f", "c", "ind", "place")}
    for iname, ind in INDENTERS.items():
        for kind, c in places:
            key = folder / f"{iname.replace(' ', '')}_{c[0] * 1e6:.0f}_{c[1] * 1e6:.0f}.npz"
            if not key.exists():
                made = made or truth(lay, name)
                d, jac = made.presses(ind, list(FORCES), c)
                np.savez(key, d=d, J=jac, f=np.array(FORCES))
            z = np.load(key)
            for i, f in enumerate(z["f"]):
                if f in forces:
                    rows["d"].append(gain * z["d"][i])
                    rows["J"].append(gain * z["J"][i])
                    rows["f"].append(f)
                    rows["c"].append(c)
                    rows["ind"].append(iname)
                    rows["place"].append(kind)
    return {k: np.array(v) for k, v in rows.items()}


def calibration_places(lay: Patch, n: int) -> list[tuple[str, NDArray, float]]:
    """``n`` (indenter, place, force) presses, seeded and the same for every truth: on the skin
    (≤ CAL_ON_SKIN from a taxel), ≥ CAL_MIN_DIST from every test place, 0.5–3 N."""
    rng = np.random.default_rng(2016)
    tests = np.array([c for _, c in positions(lay.xy, ids=lay.ids)])
    lo, hi = lay.xy.min(axis=0), lay.xy.max(axis=0)
    names = list(INDENTERS)
    out = []
    while len(out) < n:
        p = rng.uniform(lo, hi)
        if np.hypot(*(lay.xy - p).T).min() > CAL_ON_SKIN:
            continue
        if np.hypot(*(tests - p).T).min() < CAL_MIN_DIST:
            continue
        out.append((names[rng.integers(len(names))], p, float(rng.uniform(0.5, 3.0))))
    return out


def calibration_presses(lay: Patch, name: str, n: int) -> dict[str, NDArray]:
    """The truth's ``n`` calibration presses (cached): d (n, K) [m], f, c, ind."""
    gain = TRUTHS[name][2]
    every = calibration_places(lay, N_CAL)
    places = every[:n]
    which = zlib.crc32(repr([(i, c.round(9).tolist(), f) for i, c, f in every]).encode())
    key = CACHE / _tag(lay, name) / f"calibration_{N_CAL}_{which:08x}.npz"
    if not key.exists() or len(np.load(key)["d"]) != len(every):
        made = truth(lay, name)
        d = [made.presses(INDENTERS[i], [f], c, jacobian=False)[0][0] for i, c, f in every]
        np.savez(key, d=np.array(d))
    d = np.load(key)["d"][:n]
    return {
        "d": gain * d,
        "f": np.array([p[2] for p in places]),
        "c": np.array([p[1] for p in places]),
        "ind": np.array([p[0] for p in places]),
    }
