"""Compiled inner loops of the round-contact fit (numba, cached on disk after the first call).

The radial response tables R[family, k, j] are sampled at log radius t_k = t0 + k·dt and
distance r_j = j·step [m]; between samples they are interpolated bilinearly in (t, r). The fit
is a Levenberg–Marquardt least-squares fit of one contact (centre x, y [m], log radius t,
force F [N]) to whitened readings, restarted from several radii per family: the cost
landscape of a 2 mm-pitch skin has a valley per profile (a broad punch and a broad sphere read
alike), and a few starts find the deepest one for a few hundred microseconds of Python.
Nothing here validates its arguments: :mod:`tactile_contact.round_contact` does.
"""

from __future__ import annotations

import math

import numba
import numpy as np

_JIT = {"cache": True, "nogil": True}


@numba.njit(**_JIT)
def _response(table, f, t0, dt, step, t, r):  # pragma: no cover - compiled
    """(R, ∂R/∂t, ∂R/∂r) of family f at log radius t and distance r [m]; 0 beyond reach."""
    n_a = table.shape[1]
    n_j = table.shape[2]
    u = (t - t0) / dt
    if u < 0.0:
        u = 0.0
    if u > n_a - 1:
        u = n_a - 1.0
    k = int(u)
    if k > n_a - 2:
        k = n_a - 2
    wa = u - k
    v = r / step
    if v >= n_j - 1:
        return 0.0, 0.0, 0.0
    j = int(v)
    wr = v - j
    r00 = table[f, k, j]
    r01 = table[f, k, j + 1]
    r10 = table[f, k + 1, j]
    r11 = table[f, k + 1, j + 1]
    lo = r00 + wr * (r01 - r00)
    hi = r10 + wr * (r11 - r10)
    val = lo + wa * (hi - lo)
    d_t = (hi - lo) / dt
    d_r = ((1.0 - wa) * (r01 - r00) + wa * (r11 - r10)) / step
    return val, d_t, d_r


@numba.njit(**_JIT)
def _cost_force(table, f, t0, dt, step, xy, d, w2, x, y, t):  # pragma: no cover - compiled
    """(weighted cost Σ w²(F·R − d)², F) with F the non-negative least-squares force."""
    num = 0.0
    den = 0.0
    dd = 0.0
    for i in range(xy.shape[0]):
        r = math.hypot(x - xy[i, 0], y - xy[i, 1])
        val, _, _ = _response(table, f, t0, dt, step, t, r)
        num += w2[i] * val * d[i]
        den += w2[i] * val * val
        dd += w2[i] * d[i] * d[i]
    if den <= 0.0 or num <= 0.0:
        return dd, 0.0
    force = num / den
    return dd - force * num, force


@numba.njit(**_JIT)
def lm_fit(table, f, t0, dt, step, xy, d, w2, x, y, t, iterations):  # pragma: no cover
    """Levenberg–Marquardt from (x, y, t): returns (cost, x, y, t, F).

    Variables x, y [m], t = log radius, F [N]; residuals w_i·(F·R_i − d_i). t is clamped to
    the table, F to ≥ 0 (a negative force is no contact: the step is then rejected).
    """
    t_lo = t0
    t_hi = t0 + dt * (table.shape[1] - 1)
    cost, force = _cost_force(table, f, t0, dt, step, xy, d, w2, x, y, t)
    if force <= 0.0:
        return cost, x, y, t, 0.0
    mu = 1e-3
    jtj = np.empty((4, 4))
    jtr = np.empty(4)
    g = np.empty(4)
    rel = 1.0
    for _ in range(iterations):
        jtj[:] = 0.0
        jtr[:] = 0.0
        for i in range(xy.shape[0]):
            dx = x - xy[i, 0]
            dy = y - xy[i, 1]
            r = math.hypot(dx, dy)
            val, d_t, d_r = _response(table, f, t0, dt, step, t, r)
            if r > 1e-12:
                g[0] = force * d_r * dx / r
                g[1] = force * d_r * dy / r
            else:
                g[0] = 0.0
                g[1] = 0.0
            g[2] = force * d_t
            g[3] = val
            res = force * val - d[i]
            for a in range(4):
                jtr[a] += w2[i] * g[a] * res
                for b in range(a, 4):
                    jtj[a, b] += w2[i] * g[a] * g[b]
        for a in range(4):
            for b in range(a):
                jtj[a, b] = jtj[b, a]
        improved = False
        for _try in range(8):
            m = jtj.copy()
            for a in range(4):
                m[a, a] += mu * max(jtj[a, a], 1e-300)
            try:
                step_v = np.linalg.solve(m, -jtr)
            except Exception:  # singular: damp harder
                mu *= 10.0
                continue
            nx = x + step_v[0]
            ny = y + step_v[1]
            nt = min(max(t + step_v[2], t_lo), t_hi)
            nf = force + step_v[3]
            if nf <= 0.0:
                mu *= 4.0
                continue
            nc = 0.0
            for i in range(xy.shape[0]):
                r = math.hypot(nx - xy[i, 0], ny - xy[i, 1])
                val, _, _ = _response(table, f, t0, dt, step, nt, r)
                e = nf * val - d[i]
                nc += w2[i] * e * e
            if nc < cost:
                rel = (cost - nc) / max(cost, 1e-300)
                x, y, t, force, cost = nx, ny, nt, nf, nc
                mu = max(mu / 3.0, 1e-9)
                improved = True
                break
            mu *= 4.0
        if not improved or rel < 1e-10:
            break
    return cost, x, y, t, force


@numba.njit(**_JIT)
def coarse(table, t0, dt, step, xy, d, w2, centres, radius_index):  # pragma: no cover
    """Weighted cost of every family × tabulated radius ``radius_index`` (R,) × centre (L, 2),
    force at its non-negative optimum: (costs (F, R, L), forces (F, R, L))."""
    n_f = table.shape[0]
    cost = np.empty((n_f, radius_index.shape[0], centres.shape[0]))
    force = np.empty_like(cost)
    for f in range(n_f):
        for k in range(radius_index.shape[0]):
            t = t0 + dt * radius_index[k]
            for c in range(centres.shape[0]):
                cost[f, k, c], force[f, k, c] = _cost_force(
                    table, f, t0, dt, step, xy, d, w2, centres[c, 0], centres[c, 1], t
                )
    return cost, force


@numba.njit(**_JIT)
def fit_one(  # pragma: no cover - compiled
    table,
    t0,
    dt,
    step,
    xy,
    d,
    w2,
    centres,
    centre_radius_index,
    radius_index,
    pre,
    keep,
    iterations,
):
    """Best single contact: (cost, x, y, t, F, family); F = 0 when none has a positive force.

    Per family, the best of the lattice ``centres`` (L, 2) over a few radii
    (``centre_radius_index``) starts a short LM run of ``pre`` iterations from every start
    radius (tabulated indices ``radius_index``); the ``keep`` lowest then run to
    ``iterations``. Why so many starts: with precise readings each profile's basin is narrow
    (a 12 mm punch's edge crossing an electrode moves the readings by many σ per 0.1 mm), so
    no lattice a frame can afford lands in it, while a short LM run from each radius does.
    """
    n_f = table.shape[0]
    n_r = radius_index.shape[0]
    cand = np.full((n_f * n_r, 5), np.inf)
    fam = np.zeros(n_f * n_r, np.int64)
    n = 0
    for f in range(n_f):
        bc = np.inf
        bx = centres[0, 0]
        by = centres[0, 1]
        for k in range(centre_radius_index.shape[0]):
            t = t0 + dt * centre_radius_index[k]
            for c in range(centres.shape[0]):
                cost, force = _cost_force(
                    table, f, t0, dt, step, xy, d, w2, centres[c, 0], centres[c, 1], t
                )
                if force > 0.0 and cost < bc:
                    bc, bx, by = cost, centres[c, 0], centres[c, 1]
        if not bc < np.inf:
            continue
        for k in range(n_r):
            t = t0 + dt * radius_index[k]
            cost, x, y, tt, force = lm_fit(table, f, t0, dt, step, xy, d, w2, bx, by, t, pre)
            if force > 0.0:
                cand[n, 0] = cost
                cand[n, 1] = x
                cand[n, 2] = y
                cand[n, 3] = tt
                cand[n, 4] = force
                fam[n] = f
                n += 1
    best = (np.inf, 0.0, 0.0, 0.0, 0.0, -1)
    order = np.argsort(cand[:n, 0])
    for m in range(min(keep, n)):
        q = order[m]
        cost, x, y, t, force = lm_fit(
            table, fam[q], t0, dt, step, xy, d, w2, cand[q, 1], cand[q, 2], cand[q, 3], iterations
        )
        if force > 0.0 and cost < best[0]:
            best = (cost, x, y, t, force, fam[q])
    return best
