"""Single round contact fitted to the taxel readings through precomputed radial responses.

A skin pressed by one object most often carries one round contact. Its pressure is
axisymmetric and so is each taxel's electrode, so the compression a taxel reads depends only on
the distance r between its centre and the contact's: δ_i = F·R_s(|c − x_i|) for a contact of
profile s (family and radius), force F [N] and centre c [m]. The responses R_s(r) [m/N] are
computed offline (:func:`round_tables`) on a fine grid, far finer than any traction grid a
solver can afford online, and the online fit (:func:`fit_round_contact`) is a search over centre
and profile with the force in closed form: table look-ups (about 0.5 million on a 72-taxel
patch) and a short Nelder–Mead polish per frame.

Profiles: flat-punch-like p ∝ (a² − r²)^(−½) and Hertz-like p ∝ (a² − r²)^(½), each for
contact radii ``radii``. Between tabulated radii the response is interpolated linearly in
log a. No ROS import.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.ndimage
import scipy.optimize
from numpy.typing import ArrayLike, NDArray

from tactile_contact.elastic import regular_grid_operator
from tactile_contact.grids import disc_quadrature, distance_to_points
from tactile_contact.indenters import FlatPunch, HertzSphere

#: Families of the profile library, in table order.
FAMILIES = ("punch", "hertz")
#: Default contact radii [m]: 0.75–8 mm, about 11 % apart.
DEFAULT_RADII = tuple(float(a) for a in np.geomspace(0.75e-3, 8e-3, 23))


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

    @property
    def reach(self) -> float:
        """Largest tabulated distance [m]; beyond it the response is taken as zero."""
        return self.step * (self.table.shape[-1] - 1)

    def response(self, family: int, log_radius: float, r: ArrayLike) -> NDArray[np.float64]:
        """R [m/N] at distances r [m] for a contact radius exp(log_radius) (interpolated)."""
        la = np.log(self.radii)
        t = float(np.clip(log_radius, la[0], la[-1]))
        k = int(np.clip(np.searchsorted(la, t) - 1, 0, len(la) - 2))
        w = (t - la[k]) / (la[k + 1] - la[k])
        lo, hi = _lookup(self.table[family, k : k + 2], self.step, r)
        return (1.0 - w) * lo + w * hi

    def predict(self, fit: RoundFit, taxel_xy: ArrayLike) -> NDArray[np.float64]:
        """(K,) compression [m] that the contact ``fit`` makes at ``taxel_xy`` (K, 2) [m]."""
        xy = np.asarray(taxel_xy, dtype=np.float64)
        r = np.hypot(*(xy - np.asarray(fit.center)).T)
        return fit.force * self.response(fit.family, math.log(fit.radius), r)


def _lookup(table: NDArray, step: float, r: ArrayLike) -> NDArray[np.float64]:
    """Linear interpolation of each row of ``table`` (…, J) at distances r [m]; 0 beyond."""
    u = np.asarray(r, dtype=np.float64) / step
    j = np.minimum(u.astype(np.int64), table.shape[-1] - 2)
    w = u - j
    out = table[..., j] * (1.0 - w) + table[..., j + 1] * w
    return np.where(u <= table.shape[-1] - 1, out, 0.0)


def round_tables(
    thickness: float,
    young: float,
    poisson: float,
    taxel_radius: float,
    radii: ArrayLike = DEFAULT_RADII,
    *,
    reach: float = 0.02,
    step: float = 1.0e-4,
    cell: float = 1.0e-4,
    model: str = "love",
    psi: str | float = "exact",
) -> RoundTables:
    """Tabulate R_s(r) [m/N] for r = 0 … ``reach`` in ``step`` (float64).

    Each profile's exact cell averages on a regular ``cell`` grid are pushed through the
    effective-deflection operator of ``model`` (zero-padded FFT, :func:`regular_grid_operator`:
    ``"love"``, uniform pressure per cell, or ``"boussinesq"``, a point force p·A per cell with
    the Muscari self term of ``psi``), so that the fit and the bundle's forward matrix share
    one elastic model; the deflection field is then averaged over the electrode disc (8 × 24
    points, bilinear) at each distance. thickness h [m], young E [Pa], poisson ν,
    taxel_radius [m].
    """
    a = np.asarray(radii, dtype=np.float64)
    if a.ndim != 1 or len(a) < 2 or not np.all(np.diff(a) > 0) or not a[0] > 0:
        raise ValueError("radii must be at least two increasing positive radii [m]")
    half = reach + taxel_radius + 2 * cell
    n = 2 * math.ceil(half / cell) + 1  # odd: the contact centre is a cell centre
    op = regular_grid_operator(n, n, cell, cell, thickness, young, poisson, model, psi)
    # The Love operator takes cell pressures [Pa]; the point-force one, forces [N].
    per_cell = 1.0 if model == "love" else cell * cell
    coords = (np.arange(n) - n // 2) * cell
    gx, gy = np.meshgrid(coords, coords, indexing="ij")
    centers = np.column_stack((gx.ravel(), gy.ravel()))
    hs = np.full(2, 0.5 * cell)
    q, w = disc_quadrature(taxel_radius, 8, 24)
    dist = np.arange(round(reach / step) + 1) * step
    px = (dist[:, None] + q[None, :, 0]) / cell + n // 2
    py = (np.zeros_like(dist)[:, None] + q[None, :, 1]) / cell + n // 2
    table = np.empty((len(FAMILIES), len(a), len(dist)))
    for fi, fam in enumerate(FAMILIES):
        for ai, radius in enumerate(a):
            shape = (
                FlatPunch(radius)
                if fam == "punch"
                else HertzSphere.with_contact_radius(radius, 1.0, young, poisson)
            )
            near = np.abs(centers).max(axis=1) <= radius + cell
            p = np.zeros(len(centers))
            p[near] = shape.pressure_on_cells(centers[near], hs, 1.0, (0.0, 0.0), young, poisson)
            field = op.matvec(per_cell * p).reshape(n, n)
            vals = scipy.ndimage.map_coordinates(field, [px.ravel(), py.ravel()], order=1)
            table[fi, ai] = vals.reshape(px.shape) @ w
    return RoundTables(a, float(step), table)


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
    g = np.arange(-half, half + 1e-12, step)
    return center + np.stack(np.meshgrid(g, g, indexing="ij"), axis=-1).reshape(-1, 2)


def _scores(
    rows_lo: NDArray, rows_hi: NDArray, w: NDArray, step: float, centres: NDArray, xy, d
) -> tuple[NDArray, NDArray]:
    """(cost, force) of every profile (rows interpolated with weights w, shape (P,)) at every
    centre (L, 2): shapes (P, L). The force is the non-negative least-squares scale."""
    r = np.hypot(centres[:, None, 0] - xy[None, :, 0], centres[:, None, 1] - xy[None, :, 1])
    resp = (1.0 - w)[:, None, None] * _lookup(rows_lo, step, r)
    resp += w[:, None, None] * _lookup(rows_hi, step, r)  # (P, L, K)
    num = resp @ d
    den = np.einsum("...k,...k->...", resp, resp)
    force = np.maximum(num, 0.0) / np.where(den > 0, den, np.inf)
    return float(d @ d) - 2 * force * num + force**2 * den, force


def fit_round_contact(
    tables: RoundTables,
    taxel_xy: ArrayLike,
    delta: ArrayLike,
    start_xy: ArrayLike,
    *,
    search: float = 3.0e-3,
    near: float = 0.012,
    sigma: float | None = None,
    polish: bool = True,
) -> RoundFit | None:
    """Fit one round contact to compressions ``delta`` [m] at ``taxel_xy`` (K, 2) [m].

    Coarse to fine, vectorised: every tabulated profile on a 0.5 mm lattice within ``search``
    [m] of ``start_xy`` (one (2,) centre or several (S, 2)); then, in the best family, 17
    radii and a 0.125 mm lattice around the best; then trust-region least squares over
    centre and log-radius. Taxels
    farther than ``near`` [m] (plus the search) from the start are fitted as reading zero
    (their residual counts; a contact's far field there is below 1 µm/N). The force is the
    non-negative least-squares scale. None if no profile fits with F > 0.

    With ``sigma`` [m] (the per-taxel measurement error: quantisation and baseline offsets)
    the coarse best is followed by :func:`posterior_contact` instead of the polish: the
    returned contact is the posterior mean around it, not a least-squares point. Without
    ``polish`` the least-squares point is the best on the fine lattice (no trust-region step).
    """
    xy = np.asarray(taxel_xy, dtype=np.float64)
    d = np.asarray(delta, dtype=np.float64)
    c0 = np.asarray(start_xy, dtype=np.float64).reshape(-1, 2)
    local = distance_to_points(xy, c0) <= min(near, tables.reach) + search
    if not local.any():
        return None
    xl, dl = xy[local], d[local]
    rest = float(d[~local] @ d[~local])
    n_f, n_a, _ = tables.table.shape
    flat = tables.table.reshape(n_f * n_a, -1)
    lattice = np.concatenate([_lattice(c, search, 5e-4) for c in c0])
    cost, force = _scores(flat, flat, np.zeros(n_f * n_a), tables.step, lattice, xl, dl)
    pi, li = np.unravel_index(int(np.argmin(cost)), cost.shape)
    if force[pi, li] <= 0:
        return None
    fam = int(pi) // n_a
    la = np.log(tables.radii)
    t_best, c_best = float(la[int(pi) % n_a]), lattice[li]
    if sigma is not None:
        # The posterior's own 0.25 mm lattice around the coarse best replaces the polish.
        coarse = RoundFit(
            float(force[pi, li]),
            (float(c_best[0]), float(c_best[1])),
            fam,
            float(tables.radii[int(pi) % n_a]),
            math.sqrt(max(float(cost[pi, li]), 0.0) + rest),
        )
        return posterior_contact(tables, xy, d, coarse, sigma)
    # Into the basin: finer radii and a 0.125 mm lattice around the coarse best.
    ts = np.clip(t_best + np.linspace(-2, 2, 17) * float(np.mean(np.diff(la))), la[0], la[-1])
    k = np.clip(np.searchsorted(la, ts) - 1, 0, n_a - 2)
    w = (ts - la[k]) / (la[k + 1] - la[k])
    centres = _lattice(c_best, 5e-4, 1.25e-4)
    cost, force = _scores(
        tables.table[fam, k], tables.table[fam, k + 1], w, tables.step, centres, xl, dl
    )
    pi, li = np.unravel_index(int(np.argmin(cost)), cost.shape)
    v0 = np.array([*centres[li], ts[pi]])
    if not polish:
        f = float(force[pi, li])
        if f <= 0:
            return None
        res = math.sqrt(max(float(cost[pi, li]), 0.0) + rest)
        return RoundFit(f, (float(v0[0]), float(v0[1])), fam, float(np.exp(v0[2])), res)

    def residual(v: NDArray) -> NDArray[np.float64]:
        """Variable projection: the force is eliminated in closed form."""
        rv = tables.response(fam, v[2], np.hypot(*(xl - v[:2]).T))
        nn = float(rv @ rv)
        f = max(float(rv @ dl), 0.0) / nn if nn > 0 else 0.0
        return f * rv - dl

    # Then continuous (trust-region least squares): centre and size trade off along a
    # shallow valley that no lattice spans cheaply.
    scale = np.array([1e-3, 1e-3, 1.0])
    opt = scipy.optimize.least_squares(
        residual,
        v0,
        bounds=([-np.inf, -np.inf, la[0]], [np.inf, np.inf, la[-1]]),
        x_scale=scale,
        diff_step=1e-6 / scale,
        xtol=1e-10,
        max_nfev=50,
    )
    v = opt.x if 2 * opt.cost <= float(cost[pi, li]) else v0
    rv = tables.response(fam, v[2], np.hypot(*(xl - v[:2]).T))
    f = max(float(rv @ dl), 0.0) / float(rv @ rv)
    if f <= 0:
        return None
    res = float(np.sum((f * rv - dl) ** 2)) + rest
    return RoundFit(f, (float(v[0]), float(v[1])), fam, float(np.exp(v[2])), math.sqrt(res))


def posterior_contact(
    tables: RoundTables,
    taxel_xy: ArrayLike,
    delta: ArrayLike,
    fit: RoundFit,
    sigma: float,
    *,
    half: float = 1.5e-3,
    step: float = 2.5e-4,
    near: float = 0.015,
) -> RoundFit:
    """Posterior mean of one round contact around a first estimate ``fit``.

    Why: with one strongly loaded taxel and neighbours that read a few counts, centre, size and
    force trade off along a valley whose residual changes by less than the fixed per-taxel
    errors (quantisation, the driver's baseline offsets: ±½ count each). The least-squares
    point then rides those errors (tens of % in force, ~1 mm in centre, the same way every
    frame of a static press); the mean over the valley does not.

    Model: δ_i = F·R_s(|c − x_i|) + e_i with e_i ~ N(0, ``sigma``²) [m]; uniform prior over
    the centre on a ``step`` lattice within ``half`` [m] of the fit's centre, over both
    families and over the contact radius a (the tabulated radii weighted by a, since they are
    log-spaced), F at its conditional optimum (profile likelihood). Returns the posterior means
    of log F, of c and of log a; the family of largest posterior mass; and as ``residual`` the
    least residual met on the lattice (or the fit's, if smaller) [m] over all taxels. Taxels
    within ``near`` [m] of the fit's centre are fitted, the others as reading zero.
    """
    xy = np.asarray(taxel_xy, dtype=np.float64)
    d = np.asarray(delta, dtype=np.float64)
    if not (math.isfinite(sigma) and sigma > 0):
        raise ValueError(f"sigma must be finite and > 0 [m], got {sigma!r}")
    local = np.hypot(*(xy - np.asarray(fit.center)).T) <= near
    rest = float(d[~local] @ d[~local])
    n_f, n_a, _ = tables.table.shape
    flat = tables.table.reshape(n_f * n_a, -1)
    centres = _lattice(np.asarray(fit.center), half, step)
    cost, force = _scores(
        flat, flat, np.zeros(n_f * n_a), tables.step, centres, xy[local], d[local]
    )
    ok = force > 0
    if not ok.any():
        return fit
    cost = np.where(ok, cost, np.inf)
    w = np.exp(-(cost - cost.min()) / (2.0 * sigma**2))
    # Uniform prior in the radius itself, not in its logarithm: the tabulated radii are
    # log-spaced, and the many small ones all look alike under a 2 mm electrode (their
    # volume would pull the force low).
    w *= np.tile(tables.radii, n_f)[:, None]
    w /= w.sum()
    log_force = float(np.sum(w * np.log(np.where(ok, force, 1.0))))
    by_profile = w.sum(axis=1).reshape(n_f, n_a)
    center = w.sum(axis=0) @ centres
    log_radius = float(by_profile.sum(axis=0) @ np.log(tables.radii))
    return RoundFit(
        math.exp(log_force),
        (float(center[0]), float(center[1])),
        int(np.argmax(by_profile.sum(axis=1))),
        math.exp(log_radius),
        min(fit.residual, math.sqrt(max(float(cost.min()), 0.0) + rest)),
    )
