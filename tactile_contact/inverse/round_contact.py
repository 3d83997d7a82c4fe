"""Single round contact fitted to the taxel readings through precomputed radial responses.

A skin pressed by one object most often carries one round contact. Its pressure is
axisymmetric and so is each taxel's electrode, so the compression a taxel reads depends only on
the distance r between its centre and the contact's: δ_i = F·R_s(|c − x_i|) for a contact of
profile s (family and radius), force F [N] and centre c [m]. The responses R_s(r) [m/N] are
computed offline (:func:`round_tables`) on a fine grid, far finer than any traction grid a
solver can afford online, and the online fit (:func:`fit_round_contact`) is a compiled
multi-start Levenberg–Marquardt least-squares fit over centre, profile and force (a few
hundred microseconds per frame).

Profiles: flat-punch-like p ∝ (a² − r²)^(−½) and Hertz-like p ∝ (a² − r²)^(½), each for
log-spaced contact radii ``radii``. Between tabulated radii the response is interpolated
linearly in log a at distances scaled with the radius (an edge stays at the contact's
radius: :func:`tactile_contact.inverse._round_kernels._response`). No ROS import.
"""

from __future__ import annotations

import functools
import hashlib
import math
import weakref
from dataclasses import dataclass

import numpy as np
import scipy.ndimage
import scipy.signal
from numpy.typing import ArrayLike, NDArray

from tactile_contact.inverse.reductions import norm
from tactile_contact.model.elastic.axisymmetric import round_responses
from tactile_contact.model.elastic.toeplitz import grid_kernel
from tactile_contact.model.grids import disc_quadrature, distance_to_points
from tactile_contact.model.indenters import FlatPunch, HertzSphere

#: RoundTables.shared's tables, by (step, content digest); an entry goes with its last user.
_SHARED: weakref.WeakValueDictionary[tuple[float, str], RoundTables] = weakref.WeakValueDictionary()

#: Families of the profile library, in table order.
FAMILIES = ("punch", "hertz")
#: Default contact radii [m]: 0.4–9.6 mm, 5 % apart (log-spaced: the fit interpolates in
#: log radius on a uniform grid). 23 radii 11 % apart left 2–5 % model error between them.
DEFAULT_RADII = tuple(float(a) for a in np.geomspace(0.4e-3, 9.6e-3, 64))
#: Distance step [m] of the tables (linear between samples) for taxels that average over an
#: electrode disc ...
TABLE_STEP = 1.0e-4
#: ... and for point taxels (footprint 0), which read a √-shaped kink next to a punch's edge: at
#: 0.1 mm, noise-free 12 mm punches read through a converged truth came back 5–8 % high
#: (bench_valleys, 4 of 600); at 0.05 mm, none of 600.
POINT_TABLE_STEP = 5.0e-5


def table_step(footprint: float) -> float:
    """The tables' distance step [m] for taxels averaging over a disc of ``footprint`` [m]."""
    return POINT_TABLE_STEP if footprint == 0 else TABLE_STEP


@dataclass(frozen=True)
class RoundTables:
    """Radial responses of one electrode-averaged taxel to unit-force round contacts.

    Attributes:
        radii: (A,) contact radii [m], increasing.
        step: spacing of the distance samples [m]; sample j is at r = j·step.
        table: (len(FAMILIES), A, J) compression [m] per newton at distance j·step.
    """

    radii: NDArray[np.float64]
    step: float
    table: NDArray[np.float64]

    def __post_init__(self) -> None:
        la = np.log(np.asarray(self.radii, dtype=np.float64))
        if la.ndim != 1 or len(la) < 2 or not np.allclose(np.diff(la), la[1] - la[0], rtol=1e-6):
            raise ValueError("round tables need at least two log-spaced radii (np.geomspace)")
        if self.table.shape[:2] != (len(FAMILIES), len(la)) or self.table.shape[2] < 2:
            raise ValueError(f"round table shape {self.table.shape} does not match the radii")
        object.__setattr__(
            self, "_log_grid", (float(la[0]), float((la[-1] - la[0]) / (len(la) - 1)))
        )
        # The compiled fit reads the table row-major.
        object.__setattr__(self, "table", np.ascontiguousarray(self.table, dtype=np.float64))

    @classmethod
    def shared(cls, radii: ArrayLike, step: float, table: ArrayLike) -> RoundTables:
        """Tables equal to ``RoundTables(radii, step, table)``, one object for all equal ones
        alive in this process (its arrays read-only).

        Why: the patches of a skin built from the same modules and the same response have equal
        tables (≈ 0.2 MB each, with the posterior's distance-major copy 0.4 MB); a node
        serving 24 of them read 24 copies in turn (24 patches' frames interleaved: mean
        339 µs a frame with a copy each, 308–322 µs shared)."""
        # Copies: the caller's arrays stay writeable.
        radii = np.array(radii, dtype=np.float64, order="C")
        table = np.array(table, dtype=np.float64, order="C")
        digest = hashlib.blake2b(digest_size=16)
        for a in (radii, table):
            digest.update(repr(a.shape).encode())
            digest.update(a.tobytes())
        key = (float(step), digest.hexdigest())
        found = _SHARED.get(key)
        if found is None:
            radii.flags.writeable = table.flags.writeable = False
            found = cls(radii, float(step), table)
            _SHARED[key] = found
        return found

    @property
    def log_grid(self) -> tuple[float, float]:
        """(log of the first radius, log spacing) of the radius axis."""
        return self._log_grid  # type: ignore[attr-defined]

    @property
    def reach(self) -> float:
        """Largest tabulated distance [m]; beyond it the response is taken as zero."""
        return self.step * (self.table.shape[-1] - 1)

    def response(self, family: int, log_radius: float, r: ArrayLike) -> NDArray[np.float64]:
        """R [m/N] at distances r [m] for a contact radius exp(log_radius) (interpolated)."""
        from tactile_contact.inverse._round_kernels import responses

        t0, dt = self.log_grid
        dist = np.asarray(r, dtype=np.float64)
        flat = responses(self.table, family, t0, dt, self.step, log_radius, dist.reshape(-1))
        return flat.reshape(dist.shape)

    def profile_rows(self, stride: int = 1) -> tuple[NDArray, NDArray, NDArray]:
        """(rows (J, P), log radius (P,), family (P,)) of the profiles of every family at every
        ``stride``-th tabulated radius: the table distance-major (one distance's responses of
        every profile contiguous, as :func:`tactile_contact.inverse._round_kernels.posterior_mean`
        reads them). Built once per stride; read-only."""
        cache = self.__dict__.setdefault("_rows", {})
        if stride not in cache:
            sub = self.table[:, ::stride]
            n_f, n_a, n_j = sub.shape
            rows = np.ascontiguousarray(sub.transpose(2, 0, 1).reshape(n_j, n_f * n_a))
            t0, dt = self.log_grid
            log_radius = np.tile(t0 + dt * stride * np.arange(n_a), n_f)
            family = np.repeat(np.arange(n_f, dtype=np.int64), n_a)
            for a in (rows, log_radius, family):
                a.flags.writeable = False
            cache[stride] = (rows, log_radius, family)
        return cache[stride]

    def predict(self, fit: RoundFit, taxel_xy: ArrayLike) -> NDArray[np.float64]:
        """(K,) compression [m] that the contact ``fit`` makes at ``taxel_xy`` (K, 2) [m]."""
        from tactile_contact.inverse._round_kernels import predict

        xy = np.ascontiguousarray(taxel_xy, dtype=np.float64).reshape(-1, 2)
        t0, dt = self.log_grid
        x, y = fit.center
        return predict(
            self.table, fit.family, t0, dt, self.step, xy, x, y, math.log(fit.radius), fit.force
        )


def round_tables(
    thickness: float,
    young: float,
    poisson: float,
    taxel_radius: float,
    radii: ArrayLike = DEFAULT_RADII,
    *,
    reach: float = 0.02,
    step: float | None = None,
    cell: float = 1.0e-4,
    model: str = "love",
    psi: str | float = "exact",
) -> RoundTables:
    """Tabulate R_s(r) [m/N] for r = 0 … ``reach`` in ``step`` [m] (default
    :func:`table_step` of ``taxel_radius``; float64).

    Point taxels (``taxel_radius`` 0, model ``"love"``) read the continuum
    (:mod:`tactile_contact.model.elastic.axisymmetric`). Otherwise each profile's exact cell
    averages on a regular ``cell`` grid are convolved (FFT) with the effective-deflection
    kernel of ``model`` (:func:`grid_kernel`, as :func:`regular_grid_operator`'s: ``"love"``,
    uniform pressure per cell, or ``"boussinesq"``, a point force p·A per cell with the
    Muscari self term of ``psi``), so that the fit and the bundle's forward matrix share one
    elastic model; the deflection field is then averaged over the electrode disc (8 × 24
    points, bilinear) at each distance. thickness h [m], young E [Pa], poisson ν,
    taxel_radius [m].
    """
    a = np.asarray(radii, dtype=np.float64)
    if a.ndim != 1 or len(a) < 2 or not np.all(np.diff(a) > 0) or not a[0] > 0:
        raise ValueError("radii must be at least two increasing positive radii [m]")
    if not np.allclose(np.diff(np.log(a)), math.log(a[1] / a[0]), rtol=1e-6):
        raise ValueError("radii must be log-spaced (np.geomspace)")
    if step is None:
        step = table_step(taxel_radius)
    profiles = [(fi, float(r)) for fi in range(len(FAMILIES)) for r in a]
    table = radial_responses(
        thickness,
        young,
        poisson,
        [taxel_radius],
        profiles,
        reach=reach,
        step=step,
        cell=cell,
        model=model,
        psi=psi,
    )
    return RoundTables(a, float(step), table[:, 0].reshape(len(FAMILIES), len(a), -1))


def radial_responses(
    thickness: float,
    young: float,
    poisson: float,
    footprints: ArrayLike,
    profiles: list[tuple[int, float]],
    *,
    reach: float = 0.02,
    step: float = TABLE_STEP,
    cell: float = 1.0e-4,
    model: str = "love",
    psi: str | float = "exact",
) -> NDArray[np.float64]:
    """(P, F, J) reading [m/N] at distance j·``step`` from unit-force round contacts
    ``profiles`` ((family index, contact radius [m]) each) for taxels averaging over a disc
    of each radius in ``footprints`` [m] (0: the centre value, from the continuum with model
    ``"love"``). One FFT field per profile serves every other footprint (:func:`round_tables`,
    which tabulates one footprint; :mod:`tactile_contact.offline.calibrate`, which fits it)."""
    fp = np.asarray(footprints, dtype=np.float64).reshape(-1)
    if not np.all(np.isfinite(fp) & (fp >= 0)):
        raise ValueError("footprints must be finite radii >= 0 [m]")
    dist = np.arange(round(reach / step) + 1) * step
    out = np.empty((len(profiles), len(fp), len(dist)))
    point = (fp == 0.0) if model == "love" else np.zeros(len(fp), dtype=bool)
    if point.any():
        # Point taxels read the field at one place, where the cells' blur of a punch's edge
        # is largest (12 % of the peak at 0.05 mm from a 6 mm punch's edge): the continuum.
        exact = round_responses(
            [(FAMILIES[fi], radius) for fi, radius in profiles], dist, thickness, young, poisson
        )
        out[:, point] = exact[:, None, :]
        if point.all():
            return out
    half = reach + float(fp.max()) + 2 * cell
    n = 2 * math.ceil(half / cell) + 1  # odd: the contact centre is a cell centre
    # The Love operator takes cell pressures [Pa]; the point-force one, forces [N].
    per_cell = 1.0 if model == "love" else cell * cell
    coords = (np.arange(n) - n // 2) * cell
    samples = []
    for r in fp:
        q, w = disc_quadrature(float(r), 8, 24)
        px = (dist[:, None] + q[None, :, 0]) / cell + n // 2
        py = (np.zeros_like(dist)[:, None] + q[None, :, 1]) / cell + n // 2
        samples.append((px, py, w))
    # The field is needed only on the cells the samples interpolate between (a strip along
    # x): it is the convolution of the contact's cells with the kernel over the offsets that
    # join the two blocks, far smaller than the whole grid's (2n)² FFT (the calibration's
    # time went there, issue 26's unnamed fits).
    lo, hi = [], []
    for m, (px, py, _) in enumerate(samples):
        if not point[m]:
            lo.append((math.floor(px.min()), math.floor(py.min())))
            hi.append((math.floor(px.max()) + 1, math.floor(py.max()) + 1))
    tx0, ty0 = (max(v, 0) for v in np.min(lo, axis=0))
    tx1, ty1 = (min(v, n - 1) for v in np.max(hi, axis=0))
    # The kernel over the offsets between those cells and the largest contact's block.
    widest = max((float(radius) for _, radius in profiles), default=0.0)
    s0, s1 = np.nonzero(np.abs(coords) <= widest + cell)[0][[0, -1]]
    kx, ky = max(tx1 - s0, s1 - tx0) + 1, max(ty1 - s0, s1 - ty0) + 1
    kernel = grid_kernel(int(kx), int(ky), cell, cell, thickness, young, poisson, model, psi)
    for k, (fi, radius) in enumerate(profiles):
        s0, s1 = np.nonzero(np.abs(coords) <= radius + cell)[0][[0, -1]]
        block = _cell_pressures(FAMILIES[fi], float(radius), n, cell, young, poisson)
        dx = np.abs(np.arange(tx0 - s1, tx1 - s0 + 1))
        dy = np.abs(np.arange(ty0 - s1, ty1 - s0 + 1))
        field = scipy.signal.fftconvolve(
            per_cell * block, kernel[dx[:, None], dy[None, :]], mode="valid"
        )  # cells tx0..tx1 × ty0..ty1
        for m, (px, py, w) in enumerate(samples):
            if point[m]:
                continue
            at = [px.ravel() - tx0, py.ravel() - ty0]
            vals = scipy.ndimage.map_coordinates(field, at, order=1)
            out[k, m] = vals.reshape(px.shape) @ w
    return out


@functools.lru_cache(maxsize=512)
def _cell_pressures(
    family: str, radius: float, n: int, cell: float, young: float, poisson: float
) -> NDArray[np.float64]:
    """Mean pressure [Pa] of a unit-force contact (``family``, contact radius [m]) centred on
    an n × n grid of ``cell`` [m] cells, on the square block of cells whose centres lie within
    radius + cell of it along both axes (off it the pressure is 0), read-only. Cached: the
    calibration asks for the same contact at other layer thicknesses (its grid over the layer
    scale, the Jacobian's step in it) and the same family tables round after round, and the
    exact cell average was a third of its time."""
    coords = (np.arange(n) - n // 2) * cell
    # One quadrant (the axes' cells included), mirrored: the contact is centred on a cell.
    near = coords[(coords >= 0) & (coords <= radius + cell)]
    gx, gy = np.meshgrid(near, near, indexing="ij")
    centers = np.column_stack((gx.ravel(), gy.ravel()))
    shape = (
        FlatPunch(radius)
        if family == "punch"
        else HertzSphere.with_contact_radius(radius, 1.0, young, poisson)
    )
    p = shape.pressure_on_cells(centers, np.full(2, 0.5 * cell), 1.0, (0.0, 0.0), young, poisson)
    p = p.reshape(len(near), len(near))
    p = np.concatenate((p[:0:-1], p), axis=0)
    p = np.concatenate((p[:, :0:-1], p), axis=1)
    p.flags.writeable = False
    return p


@dataclass(frozen=True)
class RoundFit:
    """Best single round contact: force [N], centre (x, y) [m], family index into FAMILIES,
    contact radius [m] and the residual ‖F·R − δ‖ [m] over the fitted taxels."""

    force: float
    center: tuple[float, float]
    family: int
    radius: float
    residual: float

    def indenter(self, young: float, poisson: float) -> FlatPunch | HertzSphere:
        """The fitted profile as an indenter of this contact radius at this force."""
        if FAMILIES[self.family] == "punch":
            return FlatPunch(self.radius)
        return HertzSphere.with_contact_radius(self.radius, self.force, young, poisson)


def _lattice(center: NDArray, half: float, step: float) -> NDArray[np.float64]:
    """(L, 2) centres on a square lattice of ``step`` within ``half`` of ``center`` [m]."""
    return center + _lattice_offsets(half, step)


def _grown_lattice(
    center: NDArray, half: float, step: float, shift: NDArray
) -> NDArray[np.float64]:
    """(L, 2) centres [m] of the ``step`` lattice within ``half`` of ``center`` grown to also
    cover that lattice moved by ``shift`` (2,) steps: the same points and more."""
    n = round(half / step)
    axes = [np.arange(min(-n, k - n), max(n, k + n) + 1) * step for k in shift.tolist()]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 2)
    return center + grid


@functools.lru_cache(maxsize=16)
def _lattice_offsets(half: float, step: float) -> NDArray[np.float64]:
    g = np.arange(-half, half + 1e-12, step)
    out = np.stack(np.meshgrid(g, g, indexing="ij"), axis=-1).reshape(-1, 2)
    out.flags.writeable = False
    return out


def fit_round_contact(
    tables: RoundTables,
    taxel_xy: ArrayLike,
    delta: ArrayLike,
    start_xy: ArrayLike,
    *,
    search: float | None = None,
    near: float = 0.015,
    sigma: float | ArrayLike | None = None,
    polish: bool = True,
    thorough: bool = False,
) -> RoundFit | None:
    """Least-squares fit of one round contact to compressions ``delta`` [m] at ``taxel_xy``
    (K, 2) [m]: centre, profile (family and contact radius) and force.

    Around each start (``start_xy``: one (2,) centre or several (S, 2)) a SEARCH_PITCH lattice
    within ``search`` [m] (default SEARCH_HALF) gives every family and about SEARCH_RADII
    tabulated radii (evenly spread) their best centre; the FIT_CANDIDATES best of those
    run a few Levenberg–Marquardt steps, the FIT_KEEP best of these to convergence
    (:func:`tactile_contact.inverse._round_kernels.fit_near`, one compiled call). ``thorough``:
    a wider lattice (THOROUGH_HALF), every radius and more candidates, for readings the usual
    search left unexplained (≈ 2–3× its cost; :func:`hop_round_contact` looks around a fit).
    The force is a fitted variable kept ≥ 0. Taxels farther than ``near`` [m] from every
    start are left out of the fit (their readings count in ``residual``). ``sigma`` [m], a
    scalar or one per taxel, weights the readings (default: equal weights). ``polish`` False
    stops at fewer iterations (model choice between one and several contacts). None if no
    profile fits with F > 0.
    """
    from tactile_contact.inverse._round_kernels import fit_near

    xy = np.ascontiguousarray(taxel_xy, dtype=np.float64)
    d = np.ascontiguousarray(delta, dtype=np.float64)
    c0 = np.ascontiguousarray(start_xy, dtype=np.float64).reshape(-1, 2)
    t0, dt = tables.log_grid
    if search is None:
        search = THOROUGH_HALF if thorough else SEARCH_HALF
    # The taxels near a start, the lattices around the starts, the search and the prediction
    # at every taxel in one compiled call (as _near and _round_fit would, step by step).
    found, best, pred = fit_near(
        tables.table,
        t0,
        dt,
        tables.step,
        xy,
        d,
        _weights(sigma, d),
        c0,
        _lattice_offsets(search, SEARCH_PITCH),
        min(near, tables.reach),
        _every(len(tables.radii), 1 if thorough else len(tables.radii) // SEARCH_RADII),
        THOROUGH_CANDIDATES if thorough else FIT_CANDIDATES,
        FIT_PRE_ITERATIONS,
        THOROUGH_KEEP if thorough else FIT_KEEP,
        FIT_ITERATIONS if polish else FIT_PRE_ITERATIONS * 2,
    )
    _cost, x, y, t, force, fam = best
    if not (found and force > 0):
        return None
    res = norm(pred - d)
    return RoundFit(float(force), (float(x), float(y)), int(fam), float(math.exp(t)), res)


def _weights(sigma: float | ArrayLike | None, d: NDArray) -> NDArray[np.float64]:
    """(K,) weights 1/σ² of readings ``d`` (1 without ``sigma``; a scalar for every taxel)."""
    if sigma is None:
        return np.ones(len(d))
    s = np.asarray(sigma, dtype=np.float64)
    if s.shape != d.shape:
        s = np.broadcast_to(s, d.shape)  # (a scalar; else it names the wrong shape)
    return np.ascontiguousarray(1.0 / np.square(s))


def hop_round_contact(
    tables: RoundTables,
    taxel_xy: ArrayLike,
    delta: ArrayLike,
    fit: RoundFit,
    *,
    near: float = 0.015,
    sigma: float | ArrayLike | None = None,
) -> RoundFit | None:
    """The best least-squares round contact started around ``fit``: from its centre moved by
    HOP_SHIFTS [m] in eight directions, its radius scaled by HOP_SCALES, either family; around
    a fit at least NEEDLE_RADIUS wide also punches on a lattice (NEEDLE_HALF, NEEDLE_PITCH,
    radius × NEEDLE_SCALES); a few Levenberg–Marquardt steps each, the THOROUGH_KEEP best to
    convergence. Arguments and result as :func:`fit_round_contact`.

    Why: a broad contact read by point-like taxels has narrow valleys side by side (a 12 mm
    punch: 0.7 mm and 4 % in radius apart, each ≈ 0.3 mm and 5 % wide), and a lattice of
    tabulated radii ranks the wrong one first when the true radius lies between two
    tabulated ones (the cost at the true centre rose from 0 to 11 σ² with the radius 1.7 %
    off). The punch lattice: a 12 mm punch's valley is a needle that the search's fit (a
    sphere or a punch up to 2.5 mm and 30 % in radius off) and the hops around it missed
    (bench_valleys, seed 7: 2.51 N reported at −45 %, 1.2 mm off; 2.36 N at −10 %, 2.6 mm);
    the lattice's 324 more starts run only in this branch (readings the search left
    unexplained) and only for broad fits."""
    xy = np.asarray(taxel_xy, dtype=np.float64)
    d = np.asarray(delta, dtype=np.float64)
    c = np.asarray(fit.center, dtype=np.float64)
    found = _near(tables, xy, d, c[None], near, sigma)
    if found is None:
        return None
    local, w2 = found
    starts = np.array(
        [
            (c[0] + dx, c[1] + dy, math.log(fit.radius * k), fam)
            for dx, dy in _hop_shifts()
            for k in HOP_SCALES
            for fam in range(len(FAMILIES))
        ]
    )
    if fit.radius >= NEEDLE_RADIUS:
        starts = np.concatenate((starts, _needle_starts(c, fit.radius)))
    return _fit_from_starts(tables, xy, d, local, w2, starts, THOROUGH_KEEP)


def _fit_from_starts(
    tables: RoundTables,
    xy: NDArray,
    d: NDArray,
    local: NDArray,
    w2: NDArray,
    starts: NDArray,
    keep: int,
) -> RoundFit | None:
    """The compiled search from ``starts`` (x, y, log radius, family) over the taxels
    ``local`` with weights ``w2``, the ``keep`` best refined to convergence, as a RoundFit
    with its residual over every taxel xy [m] (readings d [m])."""
    from tactile_contact.inverse._round_kernels import fit_from

    t0, dt = tables.log_grid
    best = fit_from(
        tables.table,
        t0,
        dt,
        tables.step,
        np.ascontiguousarray(xy[local]),
        np.ascontiguousarray(d[local]),
        np.ascontiguousarray(w2),
        starts,
        FIT_PRE_ITERATIONS,
        keep,
        FIT_ITERATIONS,
    )
    return _round_fit(tables, xy, d, best)


def _round_fit(tables: RoundTables, xy: NDArray, d: NDArray, best: tuple) -> RoundFit | None:
    """The kernels' (cost, x, y, t, F, family) as a RoundFit with its residual over xy, or
    None without a positive force."""
    from tactile_contact.inverse._round_kernels import predict

    _cost, x, y, t, force, fam = best
    if not force > 0:
        return None
    t0, dt = tables.log_grid
    pred = predict(tables.table, fam, t0, dt, tables.step, np.ascontiguousarray(xy), x, y, t, force)
    res = norm(pred - d)
    return RoundFit(float(force), (float(x), float(y)), int(fam), float(math.exp(t)), res)


def rescan_round_contact(
    tables: RoundTables,
    taxel_xy: ArrayLike,
    delta: ArrayLike,
    fit: RoundFit,
    *,
    near: float = 0.015,
    sigma: float | ArrayLike | None = None,
) -> RoundFit | None:
    """The best least-squares round contact started from ``fit``'s centre at each of
    RESCAN_RADII [m], either family: a few Levenberg–Marquardt steps each, the FIT_KEEP best to
    convergence. Arguments and result as :func:`fit_round_contact`.

    Why: a broad punch and a broad sphere read alike, and the search, which gives each
    tabulated radius its best lattice centre, can end on a broad punch where a sphere through
    the same centre explains the readings better (a 12 mm sphere between three taxels at
    1.8 N, 1 % noise, fitted as a 6.1 mm punch at −33 %, 28 σ² above the sphere's valley)."""
    xy = np.asarray(taxel_xy, dtype=np.float64)
    d = np.asarray(delta, dtype=np.float64)
    c = np.asarray(fit.center, dtype=np.float64)
    found = _near(tables, xy, d, c[None], near, sigma)
    if found is None:
        return None
    local, w2 = found
    starts = np.array(
        [(c[0], c[1], math.log(a), fam) for a in RESCAN_RADII for fam in range(len(FAMILIES))]
    )
    return _fit_from_starts(tables, xy, d, local, w2, starts, FIT_KEEP)


def _needle_starts(c: NDArray, radius: float) -> NDArray[np.float64]:
    """(N, 4) punch starts (x, y, log radius, family) around a broad fit's centre ``c`` [m]
    and radius [m]: a NEEDLE_PITCH lattice within NEEDLE_HALF, radius × NEEDLE_SCALES."""
    g = _lattice_offsets(NEEDLE_HALF, NEEDLE_PITCH)
    k = np.log(radius * np.asarray(NEEDLE_SCALES))
    out = np.empty((len(g) * len(k), 4))
    out[:, :2] = np.repeat(c + g, len(k), axis=0)
    out[:, 2] = np.tile(k, len(g))
    out[:, 3] = FAMILIES.index("punch")
    return out


@functools.lru_cache(maxsize=1)
def _hop_shifts() -> tuple[tuple[float, float], ...]:
    """The centre shifts [m] of :func:`hop_round_contact`: none, and HOP_SHIFTS in eight
    directions."""
    out = [(0.0, 0.0)]
    for r in HOP_SHIFTS:
        for k in range(8):
            out.append((r * math.cos(k * math.pi / 4), r * math.sin(k * math.pi / 4)))
    return tuple(out)


def _near(
    tables: RoundTables,
    xy: NDArray,
    d: NDArray,
    centres: NDArray,
    near: float,
    sigma: float | ArrayLike | None,
) -> tuple[NDArray[np.bool_], NDArray[np.float64]] | None:
    """(taxels within ``near`` [m] (and the tables' reach) of any of ``centres`` (S, 2),
    their weights 1/σ² (1 without ``sigma``)), or None when there are none."""
    reach = min(near, tables.reach)
    if len(centres) == 1:  # (following: the general nearest-point search cost 3× more)
        dx, dy = xy[:, 0] - centres[0, 0], xy[:, 1] - centres[0, 1]
        local = dx * dx + dy * dy <= reach * reach
    else:
        local = distance_to_points(xy, centres) <= reach
    n = int(np.count_nonzero(local))
    if n == 0:
        return None
    if sigma is None:
        return local, np.ones(n)
    sigma = np.asarray(sigma, dtype=np.float64)
    if sigma.shape != d.shape:
        sigma = np.broadcast_to(sigma, d.shape)  # (a scalar; else it names the wrong shape)
    return local, 1.0 / np.square(sigma[local])


def follow_round_contact(
    tables: RoundTables,
    taxel_xy: ArrayLike,
    delta: ArrayLike,
    previous: RoundFit,
    *,
    near: float = 0.015,
    sigma: float | ArrayLike | None = None,
    other_family: bool = True,
) -> RoundFit | None:
    """Least-squares fit of one round contact started from ``previous`` (the last frame's
    contact on this patch): a Levenberg–Marquardt run from its centre and radius, once per
    family (``other_family`` False: its family only), the lower cost kept. Arguments and
    result as :func:`fit_round_contact`.

    Why: at 50 Hz a contact moves a fraction of a millimetre between frames, so it is already
    in the basin the multi-start search would find, for a tenth of the search's cost. The
    caller must check that the result explains the readings (a contact that jumped or a second
    one that appeared lands in another basin): this finds a local optimum only.
    """
    from tactile_contact.inverse._round_kernels import lm_fit, predict

    xy = np.asarray(taxel_xy, dtype=np.float64)
    d = np.asarray(delta, dtype=np.float64)
    x0, y0 = previous.center
    found = _near(tables, xy, d, np.array([[x0, y0]]), near, sigma)
    if found is None:
        return None
    local, w2 = found
    t0, dt = tables.log_grid
    lxy, ld = np.ascontiguousarray(xy[local]), np.ascontiguousarray(d[local])
    t_start = math.log(previous.radius)
    best = None
    for fam in (previous.family, 1 - previous.family) if other_family else (previous.family,):
        cost, x, y, t, force = lm_fit(
            tables.table, fam, t0, dt, tables.step, lxy, ld, w2, x0, y0, t_start, FIT_ITERATIONS
        )
        if force > 0.0 and (best is None or cost < best[0]):
            best = (cost, x, y, t, force, fam)
    if best is None:
        return None
    _cost, x, y, t, force, fam = best
    pred = predict(tables.table, fam, t0, dt, tables.step, np.ascontiguousarray(xy), x, y, t, force)
    res = norm(pred - d)
    return RoundFit(float(force), (float(x), float(y)), int(fam), float(math.exp(t)), res)


#: The search lattice: half-width [m] around each start and pitch [m]. Starts (the detector's
#: best bank contact, the strongest taxel, centroids of the readings) lie 1–3 mm from a
#: contact's centre; from 2 mm, on 200 noise-free random presses of a point-taxel truth with
#: its own tables, 4 ended in a false valley (2 mm electrodes: 1), from 1 mm 10 (2).
SEARCH_HALF = 2.0e-3
SEARCH_PITCH = 5.0e-4
#: About this many tabulated radii per family are candidates (every 2nd of the default 64,
#: 10 % apart; every one of fewer than 64).
SEARCH_RADII = 32
#: Candidates (start × family × radius, best lattice centre) that run FIT_PRE_ITERATIONS.
FIT_CANDIDATES = 24
#: The thorough search (``fit_round_contact(thorough=True)``): wider, every radius.
THOROUGH_HALF = 3.0e-3
THOROUGH_CANDIDATES = 1024
THOROUGH_KEEP = 8
#: hop_round_contact's centre shifts [m] and radius scales [-] around a fit.
HOP_SHIFTS = (0.4e-3, 0.8e-3, 1.2e-3)
HOP_SCALES = (0.92, 0.96, 1.0, 1.04, 1.08)
#: ... and, around a fit at least NEEDLE_RADIUS [m] wide, punch starts on a NEEDLE_PITCH [m]
#: lattice within NEEDLE_HALF [m], radius × NEEDLE_SCALES: a broad punch read by point
#: taxels has its valley in a needle (from 0.3 mm off its centre, a third of the
#: Levenberg–Marquardt starts reach it; from 1 mm, a fifth), and the search's fit (either
#: family, up to 2.5 mm and 30 % in radius off) hops past it.
NEEDLE_RADIUS = 3.0e-3
NEEDLE_HALF = 2.0e-3
NEEDLE_PITCH = 5.0e-4
NEEDLE_SCALES = (0.75, 0.86, 1.0, 1.15)
#: posterior_contact's lattice is grown to the brightest taxel (noisy readings) when that
#: taxel lies within this distance [m] of the fit's centre (a lattice of up to 23 × 23
#: centres at the default 0.5 mm step; the gaps in the ROBOSKIN's taxels are smaller).
TAXEL_SPAN = 8.0e-3
#: rescan_round_contact's radii [m] (both families, from the fit's centre).
RESCAN_RADII = tuple(float(a) for a in np.geomspace(0.8e-3, 8.0e-3, 8))


@functools.lru_cache(maxsize=16)
def _every(n: int, k: int) -> NDArray[np.int64]:
    """Indices 0, k, 2k, … below n (read-only)."""
    out = np.arange(0, n, max(int(k), 1), dtype=np.int64)
    out.flags.writeable = False
    return out


#: Levenberg–Marquardt iterations of each candidate, then of the FIT_KEEP best to convergence.
FIT_PRE_ITERATIONS = 3
FIT_KEEP = 4
FIT_ITERATIONS = 40


def posterior_contact(
    tables: RoundTables,
    taxel_xy: ArrayLike,
    delta: ArrayLike,
    fit: RoundFit,
    sigma: float,
    *,
    half: float = 1.5e-3,
    step: float = 5.0e-4,
    near: float = 0.015,
    radius_stride: int = 1,
    log_prior: float = 0.0,
) -> RoundFit:
    """Posterior mean of one round contact around the least-squares ``fit``.

    Why: when the readings are coarse against the contact's signal (8-bit counts: one count is
    ≈ 10 µm), centre, size and force trade off along a valley whose residual changes by less
    than the rounding errors, and the least-squares point rides those errors (biasing the force
    by 10–15 % the same way every frame of a static press); the mean over the valley does not.
    With precise readings the posterior collapses onto the least-squares point.

    Model: δ_i = F·R_s(|c − x_i|) + e_i, e_i ~ N(0, ``sigma``²) [m]; uniform prior over the
    centre on a ``step`` lattice within ``half`` [m] of the fit's, over both families and over
    the contact radius (the log-spaced tabulated radii weighted by a^(1 − ``log_prior``)); F at
    its conditional optimum. Returns the posterior means of log F, c and log a and the family
    of most mass; ``residual`` stays the fit's. Taxels within ``near`` [m] of the fit are used.

    ``log_prior`` t in [0, 1] (contact_fit.log_prior_blend: 0 for readings as precise as the
    driver hands them on, 1 from about 0.8 count of noise): 0 keeps the prior weighted by a;
    1 makes it uniform in log a, the scale-free prior for a contact's size. With t > 0, when
    the mean centre lies half a ``step`` or more from the lattice's centre, the lattice is
    grown (same points and spacing) to also cover itself moved there, and the posterior taken
    again over it (once); and when the brightest taxel lies beyond the lattice (up to
    TAXEL_SPAN from the fit's centre), the lattice is grown to cover it from the start.
    Why, for noisy readings (issue 26, 8-bit at 1 count): over a taxel only that taxel reads a
    light press, and a compact weak contact and a 3–6× stronger broad one off its centre read
    alike there; weights ∝ a gave the broad ones 24× the weight of the compact ones, and so
    the strong forces (a 0.5 N 6 mm sphere over a taxel at 2.49×); and the least-squares point
    is one place of a valley flat over the taxel's neighbourhood, often 1.5 mm from the taxel,
    so the lattice around it cut off the compact, light contacts over it. Where the taxels
    leave a gap beside it, the least-squares point may be a broad contact 2–7 mm off whose
    edge alone covers the taxel (a 0.2 N 12 mm sphere over a taxel of the hexagon at 1 count,
    calibrated: 4.6 mm off, 2.7 N), beyond any growth by one lattice; the lattice grown to the
    brightest taxel holds the whole valley between (that press, 60 draws: the largest
    reported force 10.7 → 4.8× the true one; at 1 N 2.47 → 1.96×). Why not always:
    with readings as precise as the driver's (the bag, bench_icub) weights ∝ a measured
    better (bench_icub forearm single contacts p90 38.5 % against 44.2 % with log a; the
    driver's readings median 9.4 against 14.8 %).

    Every tabulated radius (5 % apart; ``radius_stride`` > 1 skips some): with point-like
    taxels the likelihood is sharp in radius, and every third radius biased the mean (8-bit,
    calibrated point-taxel truth, ≥ 1 N: 11.0 % median force error against 8.5 % with all;
    0.5 mm centre steps cost nothing there).
    """
    from tactile_contact.inverse._round_kernels import posterior_mean

    if not (math.isfinite(sigma) and sigma > 0):
        raise ValueError(f"sigma must be finite and > 0 [m], got {sigma!r}")
    if not 0.0 <= log_prior <= 1.0:
        raise ValueError(f"log_prior must be within [0, 1], got {log_prior!r}")
    xy = np.asarray(taxel_xy, dtype=np.float64)
    d = np.asarray(delta, dtype=np.float64)
    local = np.hypot(xy[:, 0] - fit.center[0], xy[:, 1] - fit.center[1]) <= near
    rows, log_radii, families = tables.profile_rows(radius_stride)
    lxy, ld = np.ascontiguousarray(xy[local]), np.ascontiguousarray(d[local])
    w2 = np.full(len(ld), 1.0 / sigma**2)
    centre = np.asarray(fit.center, dtype=np.float64)
    centres = _lattice(centre, half, step)
    power = 1.0 - float(log_prior)
    found = None
    spans_taxel = False
    if log_prior > 0.0 and len(ld):
        # Noisy readings: the lattice also spans the brightest taxel (see the docstring).
        to_taxel = np.rint((lxy[int(np.argmax(ld))] - centre) / step).astype(int)
        far = int(np.abs(to_taxel).max())
        if round(half / step) < far <= round(TAXEL_SPAN / step):
            centres = _grown_lattice(centre, half, step, to_taxel)
            spans_taxel = True  # (it covers the valley between: not grown again)
    for grown in (False, True):
        mean = posterior_mean(rows, log_radii, families, tables.step, lxy, ld, w2, centres, power)
        if mean[0] == 0.0:
            break
        found = mean
        if grown or log_prior == 0.0 or spans_taxel:
            break
        shift = np.rint((np.array(mean[2:4]) - centre) / step).astype(int)
        if not shift.any():
            break
        centres = _grown_lattice(centre, half, step, shift)
    if found is None:
        return fit
    _mass, log_force, x, y, log_radius, family = found
    return RoundFit(
        math.exp(log_force),
        (float(x), float(y)),
        int(family),
        math.exp(log_radius),
        fit.residual,
    )
