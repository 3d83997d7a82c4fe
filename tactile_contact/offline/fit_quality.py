"""How well a calibration's presses pin its parameters: the fit's Jacobian, the parameter
uncertainties and correlations it gives, and a refinement of each press's contact when the
presses name no indenter.

The calibration (:mod:`tactile_contact.offline.calibrate`) fits three parameters of the taxel
response, θ = (gain, footprint radius b, layer scale s), to readings d of presses of known force
and position. Near the fit the residual r = g·F·R(b, s, contact) − d is linear in small changes
of θ and, for presses that name no indenter, of each press's contact radius a_i (a nuisance: it
is not kept, but it must be fitted, and it can take the place of θ). With J the Jacobian of r in
(θ, log a_1 … log a_N) and s² = ‖r‖² / (m − p) the residual variance per reading,

    cov = (JᵀJ)⁻¹ · s²,   σ_θ = sqrt(diag(cov))_θ,   corr_θ = cov_θθ / (σ_θ σ_θᵀ)

(the nuisance columns profiled out: cov's θ block is the marginal covariance). The footprint
enters through b² (a disc average changes a reading by ≈ b²·∇²/8, so b² is what the readings
see; at b = 0 the derivative in b vanishes). Columns are scaled to unit norm before the
inverse (they span metres to unitless gains). Derivatives are forward differences of the same
tables the calibration fits with (``radial_responses``): 1 % in s and a, 0.1 mm² in b².

No ROS import.
"""

from __future__ import annotations

import concurrent.futures as cf
import math
import multiprocessing
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:  # (calibrate imports this module)
    from tactile_contact.offline.calibrate import _PressModel

T = TypeVar("T")

#: Relative steps of the layer scale and the contact radii; step of b² [m²].
STEP_REL = 1e-2
STEP_AREA = 1e-7
#: Rounds of choosing each unnamed press's family again at the polished response
#: (:func:`free_fit`; 3 took the example in its comment from 1.7 % to 1.03 %).
REFAMILY_ROUNDS = 4
#: Parameters of θ, in the order of the Jacobian's first columns.
PARAMS = ("gain", "footprint_radius", "layer_scale")


@dataclass(frozen=True)
class Uncertainty:
    """Standard errors of the fitted parameters and their correlations.

    Attributes:
        sigma: 1-σ standard error per parameter of PARAMS (gain [-], footprint_radius [m],
            layer_scale [-]); the footprint's from σ of b² (σ_b = σ_b² / 2b, or √σ_b² when
            the fit is within that of b = 0).
        correlation: 3 × 3 correlation of (gain, b², layer scale), nuisance profiled out.
        nuisance: contact radii fitted per press (0 when the press names its indenter).
        dof: readings − fitted parameters.
    """

    sigma: dict[str, float]
    correlation: list[list[float]]
    nuisance: int
    dof: int

    def as_dict(self) -> dict[str, Any]:
        return {
            "sigma": {k: float(v) for k, v in self.sigma.items()},
            "correlation": {
                "parameters": ["gain", "footprint_area", "layer_scale"],
                "matrix": [[round(float(v), 4) for v in row] for row in self.correlation],
            },
            "nuisance_parameters": self.nuisance,
            "dof": self.dof,
        }


def unit_responses(
    model: _PressModel, scale: float, feet: NDArray, profiles: list[tuple[int, float]]
) -> NDArray[np.float64]:
    """(P, F, N, K) reading per unit gain [m] of press n pressed with profile p and its own
    force, for taxels averaging over each footprint of ``feet`` [m] at layer scale ``scale``;
    readings out of reach are 0."""
    from tactile_contact.inverse.round_contact import radial_responses

    e, m = model.patch.elastomer, model.patch.model
    tab = radial_responses(
        e.thickness * scale,
        e.young,
        e.poisson,
        feet,
        profiles,
        reach=model.reach + 2 * model.step,
        step=model.step,
        model=m.kind,
        psi=m.psi,
    )  # (P, F, J)
    resp = tab[..., model.jl] * (1 - model.w) + tab[..., model.jl + 1] * model.w  # (P, F, N, K)
    return np.where(model.use, resp * model.presses.force[:, None], 0.0)


def own(pred: NDArray, index: NDArray) -> NDArray:
    """(F, N, K) of (P, F, N, K) predictions: press n's own profile index[n]."""
    n = np.arange(len(index))
    return np.moveaxis(pred[index, :, n], 0, 1)


def press_profiles(
    model: _PressModel, scale: float, foot: float, gain: float
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Each press's profile (family, contact radius [m]) at the fit: the named indenter's, or
    for an unnamed press the best of the free profiles, refined along the radius by a parabola
    in log a through the best radius and its neighbours of the same family."""
    if model.index is not None:
        fam = np.array([model.profiles[i][0] for i in model.index], dtype=np.int64)
        rad = np.array([model.profiles[i][1] for i in model.index])
        return fam, rad
    pred = unit_responses(model, scale, np.array([foot]), model.profiles)[:, 0]  # (P, N, K)
    d, use = model.presses.deflection, model.use
    r2 = np.sum(np.where(use[None], (gain * pred - d[None]) ** 2, 0.0), axis=2)  # (P, N)
    best = np.argmin(r2, axis=0)
    fam = np.empty(len(best), dtype=np.int64)
    rad = np.empty(len(best))
    for n, p in enumerate(best):
        f, a = model.profiles[p]
        same = [i for i, q in enumerate(model.profiles) if q[0] == f]
        k = same.index(int(p))
        fam[n], rad[n] = f, a
        if 0 < k < len(same) - 1:
            x = np.log([model.profiles[same[k + j]][1] for j in (-1, 0, 1)])
            y = np.array([r2[same[k + j], n] for j in (-1, 0, 1)])
            den = y[0] - 2 * y[1] + y[2]
            if den > 0:  # the vertex, at most half a step either way
                t = float(np.clip(0.5 * (y[0] - y[2]) / den, -0.5, 0.5))
                rad[n] = math.exp(x[1] + t * (x[2] - x[1]))
    return fam, rad


def own_responses(
    model: _PressModel,
    scale: float,
    foot: float,
    fam: NDArray[np.int64],
    rad: NDArray[np.float64],
) -> NDArray[np.float64]:
    """(2, N, K) reading per unit gain [m] of each press with its own profile (fam, rad) at
    layer scale ``scale``, for footprints ``foot`` and √(foot² + STEP_AREA) [m]: what
    :func:`jacobian` starts from, and all a trial point of :func:`polish` needs."""
    profiles = [(int(f), float(a)) for f, a in zip(fam, rad, strict=True)]
    return own(unit_responses(model, scale, _feet(foot), profiles), np.arange(len(fam)))


def _feet(foot: float) -> NDArray[np.float64]:
    return np.array([foot, math.sqrt(foot * foot + STEP_AREA)])


def jacobian(
    model: _PressModel,
    scale: float,
    foot: float,
    gain: float,
    fam: NDArray[np.int64],
    rad: NDArray[np.float64],
    free: bool,
    p0: NDArray[np.float64] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(J (m, 3 + N·free), residual (m,)) over the fitted readings at (gain, foot, scale)
    with each press's profile (fam, rad); columns: gain, b² [m²], layer scale, then log a_n
    of each press when ``free``. ``p0``: :func:`own_responses` at this point, if known."""
    n = len(fam)
    idx = np.arange(n)
    feet = _feet(foot)
    if p0 is None:
        p0 = own_responses(model, scale, foot, fam, rad)
    profiles = [(int(f), float(a)) for f, a in zip(fam, rad, strict=True)]
    ps = own(unit_responses(model, scale * (1 + STEP_REL), feet[:1], profiles), idx)[0]
    use = model.use
    d = model.presses.deflection
    res = (gain * p0[0] - d)[use]
    cols = [
        p0[0][use],
        gain * (p0[1] - p0[0])[use] / STEP_AREA,
        gain * (ps - p0[0])[use] / (scale * STEP_REL),
    ]
    if free:
        # (both footprints as p0: the same field block, so the same rounding, in pa − p0)
        stepped = [(int(f), float(a) * (1 + STEP_REL)) for f, a in zip(fam, rad, strict=True)]
        pa = own(unit_responses(model, scale, feet, stepped), idx)[0]
        da = gain * (pa - p0[0]) / math.log1p(STEP_REL)  # (N, K): ∂/∂ log a_n
        rows = np.nonzero(use)[0]  # press of each fitted reading
        block = np.zeros((int(use.sum()), n))
        block[np.arange(len(rows)), rows] = da[use]
        cols.append(block)
    jac = np.column_stack([c if c.ndim == 2 else c[:, None] for c in cols])
    return jac, res


def uncertainty(
    jac: NDArray,
    res: NDArray,
    foot: float,
    free_presses: int,
    rows: NDArray[np.int64] | None = None,
    gain: float = 1.0,
) -> Uncertainty:
    """Standard errors and correlations of (gain, footprint, layer scale) from the Jacobian
    ``jac`` and residual ``res`` of :func:`jacobian` (module docstring).

    With ``rows`` (the press of each reading) and the fitted ``gain``, also ``force_scale``:
    the 1-σ relative error of the forces a bundle of this fit gives, from how θ's errors move
    each press's predicted amplitude (its projection on the prediction p = gain·J[:, 0]):
    ∂ log A_n / ∂θ_j = Σ_k J_kj p_k / (gain Σ_k p_k²), σ_n² = dᵀ cov_θ d, RMS over presses.
    Gain and layer scale are strongly anti-correlated (a thicker layer reads more per newton,
    a lower gain less): the force scale they set together is pinned far better than either.
    """
    m = jac.shape[0]
    norms = np.linalg.norm(jac, axis=0)
    live = norms > 0  # a press whose readings do not move with its radius adds nothing
    norms = np.where(live, norms, 1.0)
    a = jac / norms
    dof = max(m - int(live.sum()), 1)
    s2 = float(res @ res) / dof
    # The pseudo-inverse: a direction the presses cannot see gets an infinite σ below.
    _, sv, vt = np.linalg.svd(a, full_matrices=False)
    tiny = sv <= sv[0] * 1e-10
    inv_sv2 = np.where(tiny, 0.0, 1.0 / np.where(tiny, 1.0, sv) ** 2)
    cov = (vt.T * inv_sv2) @ vt * s2
    blind = np.abs(vt[tiny][:, :3]).max(axis=0) > 1e-6 if tiny.any() else np.zeros(3, bool)
    var = np.diag(cov)[:3]
    sig = np.sqrt(np.maximum(var, 0.0)) / norms[:3]
    sig[blind | ~live[:3]] = np.inf
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov[:3, :3] / np.sqrt(np.outer(var, var))
    s_area = float(sig[1])
    if not math.isfinite(s_area):
        s_foot = math.inf
    elif foot > math.sqrt(s_area):
        s_foot = s_area / (2 * foot)
    else:
        s_foot = math.sqrt(s_area)
    sigma = {"gain": float(sig[0]), "footprint_radius": s_foot, "layer_scale": float(sig[2])}
    if rows is not None:
        if not np.all(np.isfinite(sig)):
            sigma["force_scale"] = math.inf
        else:
            cov_t = cov[:3, :3] / np.outer(norms[:3], norms[:3])
            p = jac[:, 0]
            n = int(rows.max()) + 1 if len(rows) else 0
            pp = np.bincount(rows, p * p, minlength=n)
            ok = pp > 0
            d = np.stack(
                [
                    np.bincount(rows, jac[:, j] * p, minlength=n)[ok] / (gain * pp[ok])
                    for j in range(3)
                ],
                axis=1,
            )  # (presses, 3)
            var_n = np.einsum("ni,ij,nj->n", d, cov_t, d)
            sigma["force_scale"] = float(math.sqrt(max(float(np.mean(var_n)), 0.0)))
    return Uncertainty(
        sigma=sigma,
        correlation=np.nan_to_num(corr).tolist(),
        nuisance=free_presses,
        dof=dof,
    )


def both_families(
    model: _PressModel, scale: float, foot: float, gain: float, profiles: list
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Each unnamed press's best profile over both families of ``profiles`` ((family, radius
    [m]) pairs: the model's grid radii or its ``family_profiles``), each family's radius
    refined by a parabola in log a through its best tabulated radius and the neighbours (at
    most half a step either way); the family whose refined residual is lower wins. The
    parabola's error must stay below the two families' difference, which it does not always
    with the grid's radii 20 % apart (11 of 48 presses in the wrong family at the named fit's
    response, issue 26): hence free_fit's second table (calibrate.FAMILY_RADII, 4.7 % apart)."""
    pred = unit_responses(model, scale, np.array([foot]), profiles)[:, 0]  # (P, N, K)
    d, use = model.presses.deflection, model.use
    r2 = np.sum(np.where(use[None], (gain * pred - d[None]) ** 2, 0.0), axis=2)  # (P, N)
    n = r2.shape[1]
    best = (np.full(n, np.inf), np.zeros(n, np.int64), np.zeros(n))
    for f in sorted({q[0] for q in profiles}):
        same = np.array([i for i, q in enumerate(profiles) if q[0] == f])
        loga = np.log([profiles[i][1] for i in same])
        sub = r2[same]  # (A, N)
        k = np.argmin(sub, axis=0)
        for j in range(n):
            kk, val, la = int(k[j]), float(sub[k[j], j]), float(loga[k[j]])
            if 0 < kk < len(same) - 1:
                y0, y1, y2 = sub[kk - 1 : kk + 2, j]
                den = y0 - 2 * y1 + y2
                if den > 0:
                    t = float(np.clip(0.5 * (y0 - y2) / den, -0.5, 0.5))
                    la += t * (loga[kk + 1] - loga[kk])
                    val = float(y1 + 0.5 * t * (y2 - y0) + 0.5 * t * t * den)
            if val < best[0][j]:
                best[0][j], best[1][j], best[2][j] = val, f, math.exp(la)
    return best[1], best[2]


def polish(
    model: _PressModel,
    scale: float,
    foot: float,
    gain: float,
    fam: NDArray[np.int64],
    rad: NDArray[np.float64],
    *,
    iterations: int = 6,
    bounds: tuple[tuple[float, float], ...] = ((0.0, 4e-3), (0.75, 1.25)),
) -> tuple[float, float, float, NDArray[np.float64], NDArray, NDArray]:
    """Levenberg–Marquardt on (gain, b², layer scale, log a of each press) from a grid point:
    the contact radius of a press that names no indenter is continuous here (the grid's radii
    are 20 % apart, and the model error between them biased gain and footprint, issue 26).
    Returns (scale, foot, gain, radii, J, residual) at the best point found (J, residual as
    :func:`jacobian`'s there). ``bounds``: footprint radius [m] and layer scale."""
    (f_lo, f_hi), (s_lo, s_hi) = bounds
    jac, res = jacobian(model, scale, foot, gain, fam, rad, True)
    cost = float(res @ res)
    lam = 1e-2
    x = np.concatenate(([gain, foot * foot, scale], np.log(rad)))
    for _ in range(iterations):
        norms = np.linalg.norm(jac, axis=0)
        norms = np.where(norms > 0, norms, 1.0)
        a = jac / norms
        h = a.T @ a
        g = a.T @ res
        accepted = False
        while lam < 1e6:
            step = np.linalg.solve(h + lam * np.diag(np.diag(h) + 1e-12), -g) / norms
            xn = x + step
            xn[1] = float(np.clip(xn[1], f_lo**2, f_hi**2))
            xn[2] = float(np.clip(xn[2], s_lo, s_hi))
            xn[3:] = np.clip(xn[3:], math.log(0.3e-3), math.log(10e-3))
            rn = np.exp(xn[3:])
            # A trial needs only its residual (a third of the Jacobian's tables), and about
            # half are refused (85 of 174 in the unnamed fit of 16 presses).
            pn = own_responses(model, xn[2], math.sqrt(xn[1]), fam, rn)
            resn = (xn[0] * pn[0] - model.presses.deflection)[model.use]
            cn = float(resn @ resn)
            if cn < cost:
                jn, resn = jacobian(model, xn[2], math.sqrt(xn[1]), xn[0], fam, rn, True, pn)
                done = (cost - cn) < 1e-3 * cost
                x, jac, res, cost, accepted = xn, jn, resn, cn, True
                lam = max(lam / 4, 1e-6)
                break
            lam *= 8
        if not accepted or done:
            break
    return float(x[2]), math.sqrt(float(x[1])), float(x[0]), np.exp(x[3:]), jac, res


def free_fit(
    model: _PressModel,
    cost: NDArray,
    gains: NDArray,
    feet: NDArray,
    scales: NDArray,
    grid_best: tuple[float, float, float],
    nominal: tuple[float, float, float] | None = None,
    *,
    jobs: int | None = None,
) -> tuple[Any, ...]:
    """Presses without indenter names: the grid's best point, the best grid point at the
    smallest footprint and ``nominal`` (the layout's own layer scale and footprint, with the
    best gain there), each refined with continuous contact radii (fit_quality.polish); the
    lower residual wins. With radii 20 % apart the grid's optimum can sit in a valley of its
    own (issue 26: footprint 1.25 mm, gain 1.115 on a truth of 0 mm, 1): a second start
    finds the other, and two starts that end as good and far apart say the presses cannot
    tell them apart. The nominal start: the presses' families are chosen at the response
    the skin was designed with, and a fit from the grid can lock into wrong families that
    its response compensates (1 % noise per reading, 2 mm electrode, gain 1.15: footprint
    2.09 mm, 2.2× the named fit's force error, accepted). From each start the families are
    chosen twice, over the grid's radii (``model.profiles``) and over FAMILY_RADII (4.7 %
    apart: the grid's misjudged 11 of 48 presses' families, a 1.55× force error left on the
    gain 1.15 truth at 1 % per reading; the fine table alone ended the point truth's grid
    start at 5.4 %), each polished with its rounds. Returns (scale, foot, gain, families,
    radii, J, residual, starts), ``starts`` every end, best first. The ends are independent:
    ``jobs`` processes fit them (:func:`map_jobs`), with the same result as one."""
    si0 = int(np.argmin(cost[0]))
    todo = [grid_best]
    if grid_best[1] > feet[0]:
        todo.append((float(scales[si0]), float(feet[0]), float(gains[0, si0])))
    if nominal is not None and all(
        not np.allclose(nominal[:2], t[:2], rtol=0.0, atol=1e-9) for t in todo
    ):
        todo.append(nominal)
    lims = ((float(feet[0]), float(feet[-1])), (float(scales[0]), float(scales[-1])))
    jobs_list = [(t, table) for t in todo for table in ("profiles", "family_profiles")]
    fits = map_jobs(_fit_from, [(model, t, table, lims) for t, table in jobs_list], jobs)
    starts = [
        {
            "from": [round(f0, 7), round(s0, 5), round(g0, 5)],
            "footprint_radius": fit[2],
            "layer_scale": fit[1],
            "gain": fit[3],
            "relative_residual": math.sqrt(fit[0] / model.norm2),
        }
        for ((s0, f0, g0), _), fit in zip(jobs_list, fits, strict=True)
    ]
    order = np.argsort([f[0] for f in fits])
    _, s1, f1, g1, fam, rad, jac, res = fits[order[0]]
    return s1, f1, g1, fam, rad, jac, res, [starts[i] for i in order]


def _fit_from(
    model: _PressModel,
    start: tuple[float, float, float],
    table: str,
    lims: tuple[tuple[float, float], tuple[float, float]],
) -> tuple[float, float, float, float, NDArray, NDArray, NDArray, NDArray]:
    """One end of :func:`free_fit`: each press's family chosen at ``start`` (layer scale,
    footprint [m], gain) over the model's ``table`` of profiles, polished, then chosen again
    and polished while that lowers the residual. Returns (cost [m²], scale, foot, gain,
    families, radii, J, residual)."""
    s0, f0, g0 = start
    profiles = getattr(model, table)
    fam, rad = both_families(model, s0, f0, g0, profiles)
    s1, f1, g1, rad, jac, res = polish(model, s0, f0, g0, fam, rad, bounds=lims)
    c = float(res @ res)
    # Each press's family was chosen at the start's response; the polish moves the
    # response and may leave presses with the wrong one, which the response then
    # compensates (issue 26, 1 % noise per reading, 2 mm electrode, gain 1.15: gain 1.012,
    # layer 1.091 at 1.7 % residual, where the truth's own point gives 1.0 %). Choose
    # again at the polished response and polish from there while that lowers the residual.
    for _ in range(REFAMILY_ROUNDS):
        fam2, rad2 = both_families(model, s1, f1, g1, profiles)
        if np.array_equal(fam2, fam):
            break
        cand = polish(model, s1, f1, g1, fam2, rad2, bounds=lims)
        c2 = float(cand[5] @ cand[5])
        if not c2 < c:
            break
        (s1, f1, g1, rad, jac, res), fam, c = cand, fam2, c2
    return c, s1, f1, g1, fam, rad, jac, res


def map_jobs(fn: Callable[..., T], args: list[tuple], jobs: int | None) -> list[T]:
    """``[fn(*a) for a in args]``, in up to ``jobs`` processes (1 or None: here). forkserver,
    not fork: the caller may be a ROS process whose DDS threads a forked child would inherit
    in an undefined state (as tactile_contact.offline.build)."""
    n = max(1, min(jobs or 1, len(args)))
    if n == 1:
        return [fn(*a) for a in args]
    ctx = multiprocessing.get_context("forkserver")
    with cf.ProcessPoolExecutor(max_workers=n, mp_context=ctx) as pool:
        return list(pool.map(fn, *zip(*args, strict=True)))


def ambiguous(starts: list[dict[str, float]], dof: int, limit: float) -> dict[str, float] | None:
    """The first fit (of ``starts``, best first) whose residual differs from the best one's by
    less than 3 σ of the χ² (Δχ² < 9 with the best fit's residual variance) while its gain
    differs by more than ``limit``, or None. Every end counts, the same start's under both
    family tables too: two ends of one start can sit in different valleys (issue 26, the
    point truth at 1 % of each press's peak: gains 0.997 and 0.952 at Δχ² 2.9), and what
    the presses cannot tell apart does not depend on where the search began."""
    if len(starts) < 2:
        return None
    a = starts[0]
    s2 = a["relative_residual"] ** 2 / max(dof, 1)
    for b in starts[1:]:
        dchi2 = (b["relative_residual"] ** 2 - a["relative_residual"] ** 2) / max(s2, 1e-300)
        if dchi2 >= 9.0:
            break  # (best first: the rest are further still)
        if abs(a["gain"] - b["gain"]) > limit:
            return b
    return None
