"""Compiled inner loops of the round-contact fit (numba, cached on disk after the first call).

The radial response tables R[family, k, j] are sampled at log radius t_k = t0 + k·dt and
distance r_j = j·step [m]; between samples they are interpolated linearly in r, and between
radii at scaled distances (:func:`_value`): a contact's edge stays at its radius. The fit
is a Levenberg–Marquardt least-squares fit of one contact (centre x, y [m], log radius t,
force F [N]) to whitened readings, restarted from several radii per family: the cost
landscape of a 2 mm-pitch skin has a valley per profile (a broad punch and a broad sphere read
alike), and a few starts find the deepest one for a few hundred microseconds of Python.
Nothing here validates its arguments: :mod:`tactile_contact.inverse.round_contact` does.
"""

from __future__ import annotations

import math

import numba
import numpy as np

_JIT = {"cache": True, "nogil": True}


@numba.njit(**_JIT)
def _row(table, t0, dt, t):  # pragma: no cover - compiled
    """(k, w): log radius t lies between table rows k and k + 1, at weight w of row k + 1."""
    n_a = table.shape[1]
    u = min(max((t - t0) / dt, 0.0), n_a - 1.0)
    k = min(int(u), n_a - 2)
    return k, u - k


@numba.njit(**_JIT)
def _scales(dt, wa):  # pragma: no cover - compiled
    """(a_k/a, a_(k+1)/a): the distance scales of rows k, k + 1 for a radius at weight wa."""
    s0 = math.exp(-wa * dt)
    return s0, s0 * math.exp(dt)


@numba.njit(**_JIT)
def _sample(table, f, k, v):  # pragma: no cover - compiled
    """(R, ∂R/∂v) of row (f, k) at fractional sample index v ≥ 0, linear; (0, 0) beyond reach."""
    n_j = table.shape[2]
    if v > n_j - 1:
        return 0.0, 0.0
    j = min(int(v), n_j - 2)
    lo = table[f, k, j]
    d = table[f, k, j + 1] - lo
    return lo + (v - j) * d, d


@numba.njit(**_JIT)
def _response(table, f, k, wa, dt, step, r):  # pragma: no cover - compiled
    """(R, ∂R/∂t, ∂R/∂r) of family f between rows k, k + 1 (weight wa) at distance r [m];
    0 beyond reach.

    Between radii the rows are read at scaled distances r·a_k/a and r·a_(k+1)/a and blended
    linearly in log a: every profile scales with its radius near its edge, so the blend keeps
    the edge where it is. Blending at equal distances instead put an untabulated punch's edge
    half way between its neighbours': a point taxel just inside a 6 mm punch read 19–34 %
    of the peak low, and the fit's cost grew narrow false valleys there. The far field, which
    does not scale, errs by second order only (the two scalings' first-order errors cancel:
    0.3 % of an r⁻³ decay at mid-interval for radii 5 % apart)."""
    s0, s1 = _scales(dt, wa)
    r0 = r * s0
    r1 = r * s1
    v0, g0 = _sample(table, f, k, r0 / step)
    v1, g1 = _sample(table, f, k + 1, r1 / step)
    g0 /= step
    g1 /= step
    val = v0 + wa * (v1 - v0)
    d_r = (1.0 - wa) * g0 * s0 + wa * g1 * s1
    d_t = (v1 - v0) / dt - (1.0 - wa) * g0 * r0 - wa * g1 * r1
    return val, d_t, d_r


@numba.njit(**_JIT)
def _value(table, f, k, wa, step, r, s0, s1):  # pragma: no cover - compiled
    """R of family f between rows k, k + 1 (weight wa, distance scales s0, s1 from
    :func:`_scales`) at distance r [m]; 0 beyond reach (see :func:`_response`)."""
    v0 = _sample(table, f, k, r * s0 / step)[0]
    v1 = _sample(table, f, k + 1, r * s1 / step)[0]
    return v0 + wa * (v1 - v0)


@numba.njit(**_JIT)
def _cost_force(table, f, k, wa, dt, step, xy, d, w2, x, y):  # pragma: no cover - compiled
    """(weighted cost Σ w²(F·R − d)², F) with F the non-negative least-squares force."""
    s0, s1 = _scales(dt, wa)
    num = 0.0
    den = 0.0
    dd = 0.0
    for i in range(xy.shape[0]):
        dx = x - xy[i, 0]
        dy = y - xy[i, 1]
        val = _value(table, f, k, wa, step, math.sqrt(dx * dx + dy * dy), s0, s1)
        num += w2[i] * val * d[i]
        den += w2[i] * val * val
        dd += w2[i] * d[i] * d[i]
    if den <= 0.0 or num <= 0.0:
        return dd, 0.0
    force = num / den
    return dd - force * num, force


@numba.njit(**_JIT)
def _damped_step(jtj, jtr, mu, out):  # pragma: no cover - compiled
    """Solve (JᵀJ + μ·diag JᵀJ)·s = −Jᵀr for s (4 unknowns) by Cholesky into ``out``;
    False when the damped matrix is not positive definite."""
    c = np.empty((4, 4))
    for a in range(4):
        for b in range(a + 1):
            s = jtj[a, b]
            if a == b:
                s += mu * max(jtj[a, a], 1e-300)
            for m in range(b):
                s -= c[a, m] * c[b, m]
            if a == b:
                if not s > 0.0:
                    return False
                c[a, a] = math.sqrt(s)
            else:
                c[a, b] = s / c[b, b]
    for a in range(4):  # forward: C·y = −Jᵀr
        s = -jtr[a]
        for m in range(a):
            s -= c[a, m] * out[m]
        out[a] = s / c[a, a]
    for a in range(3, -1, -1):  # back: Cᵀ·s = y
        s = out[a]
        for m in range(a + 1, 4):
            s -= c[m, a] * out[m]
        out[a] = s / c[a, a]
    return True


@numba.njit(**_JIT)
def responses(table, f, t0, dt, step, t, r):  # pragma: no cover - compiled
    """(N,) R [m/N] of family f at log radius t for distances r (N,) [m]; 0 beyond reach."""
    k, wa = _row(table, t0, dt, t)
    s0, s1 = _scales(dt, wa)
    out = np.empty(r.shape[0])
    for i in range(r.shape[0]):
        out[i] = _value(table, f, k, wa, step, r[i], s0, s1)
    return out


@numba.njit(**_JIT)
def predict(table, f, t0, dt, step, xy, x, y, t, force):  # pragma: no cover - compiled
    """(N,) compression [m] that force·R of family f at log radius t, centred at (x, y) [m],
    makes at the points ``xy`` (N, 2) [m]."""
    k, wa = _row(table, t0, dt, t)
    s0, s1 = _scales(dt, wa)
    out = np.empty(xy.shape[0])
    for i in range(xy.shape[0]):
        dx = x - xy[i, 0]
        dy = y - xy[i, 1]
        out[i] = force * _value(table, f, k, wa, step, math.sqrt(dx * dx + dy * dy), s0, s1)
    return out


@numba.njit(**_JIT)
def lm_fit(table, f, t0, dt, step, xy, d, w2, x, y, t, iterations):  # pragma: no cover
    """Levenberg–Marquardt from (x, y, t): returns (cost, x, y, t, F).

    Variables x, y [m], t = log radius, F [N]; residuals w_i·(F·R_i − d_i). t is clamped to
    the table, F to ≥ 0 (a negative force is no contact: the step is then rejected).
    """
    t_lo = t0
    t_hi = t0 + dt * (table.shape[1] - 1)
    k, wa = _row(table, t0, dt, t)
    cost, force = _cost_force(table, f, k, wa, dt, step, xy, d, w2, x, y)
    if force <= 0.0:
        return cost, x, y, t, 0.0
    mu = 1e-3
    jtj = np.empty((4, 4))
    jtr = np.empty(4)
    g = np.empty(4)
    sv = np.empty(4)
    rel = 1.0
    for _ in range(iterations):
        jtj[:] = 0.0
        jtr[:] = 0.0
        for i in range(xy.shape[0]):
            dx = x - xy[i, 0]
            dy = y - xy[i, 1]
            r = math.sqrt(dx * dx + dy * dy)
            val, d_t, d_r = _response(table, f, k, wa, dt, step, r)
            if r > 1e-12:
                g[0] = force * d_r * dx / r
                g[1] = force * d_r * dy / r
            else:
                g[0] = 0.0
                g[1] = 0.0
            g[2] = force * d_t
            g[3] = val
            res = w2[i] * (force * val - d[i])
            for a in range(4):
                jtr[a] += g[a] * res
                wg = w2[i] * g[a]
                for b in range(a + 1):
                    jtj[a, b] += wg * g[b]
        improved = False
        for _try in range(8):
            if not _damped_step(jtj, jtr, mu, sv):  # not positive definite: damp harder
                mu *= 10.0
                continue
            nx = x + sv[0]
            ny = y + sv[1]
            nt = min(max(t + sv[2], t_lo), t_hi)
            nf = force + sv[3]
            if nf <= 0.0:
                mu *= 4.0
                continue
            nk, nwa = _row(table, t0, dt, nt)
            ns0, ns1 = _scales(dt, nwa)
            nc = 0.0
            for i in range(xy.shape[0]):
                dx = nx - xy[i, 0]
                dy = ny - xy[i, 1]
                r = math.sqrt(dx * dx + dy * dy)
                e = nf * _value(table, f, nk, nwa, step, r, ns0, ns1) - d[i]
                nc += w2[i] * e * e
            if nc < cost:
                rel = (cost - nc) / max(cost, 1e-300)
                x, y, t, force, cost, k, wa = nx, ny, nt, nf, nc, nk, nwa
                mu = max(mu / 3.0, 1e-9)
                improved = True
                break
            mu *= 4.0
        if not improved or rel < 1e-10:
            break
    return cost, x, y, t, force


@numba.njit(**_JIT)
def _lattice_costs(table, t0, dt, step, xy, d, w2, centres, radius_index):  # pragma: no cover
    """Weighted cost of every family × tabulated radius ``radius_index`` (R,) × centre (L, 2),
    the force at its non-negative optimum: (costs (F, R, L), forces (F, R, L)); cost ‖d‖²_w
    and force 0 where no positive force fits. The tabulated radii's rows are
    copied distance-major, so that one taxel's look-ups over every radius are contiguous (the
    innermost loop, which the compiler vectorises), and each centre's taxel distances serve
    every family and radius."""
    n_f = table.shape[0]
    n_k = xy.shape[0]
    n_j = table.shape[2]
    n_r = radius_index.shape[0]
    rows = np.empty((n_f, n_j, n_r))
    for f in range(n_f):
        for m in range(n_r):
            for a in range(n_j):
                rows[f, a, m] = table[f, radius_index[m], a]
    dd = 0.0
    for i in range(n_k):
        dd += w2[i] * d[i] * d[i]
    cost = np.empty((n_f, n_r, centres.shape[0]))
    force = np.empty_like(cost)
    num = np.empty((n_f, n_r))
    den = np.empty((n_f, n_r))
    for c in range(centres.shape[0]):
        num[:] = 0.0
        den[:] = 0.0
        for i in range(n_k):
            dx = centres[c, 0] - xy[i, 0]
            dy = centres[c, 1] - xy[i, 1]
            v = math.sqrt(dx * dx + dy * dy) / step
            if v > n_j - 1:
                continue
            a = min(int(v), n_j - 2)
            wr = v - a
            for f in range(n_f):
                for m in range(n_r):
                    lo = rows[f, a, m]
                    val = lo + wr * (rows[f, a + 1, m] - lo)
                    num[f, m] += w2[i] * val * d[i]
                    den[f, m] += w2[i] * val * val
        for f in range(n_f):
            for m in range(n_r):
                if den[f, m] <= 0.0 or num[f, m] <= 0.0:
                    cost[f, m, c] = dd
                    force[f, m, c] = 0.0
                else:
                    force[f, m, c] = num[f, m] / den[f, m]
                    cost[f, m, c] = dd - num[f, m] / den[f, m] * num[f, m]
    return cost, force


#: Lattice points whose cost exceeds the best by more than this (χ² units) are left out of
#: the posterior: their weight e^(−Δ/2)·a^k (k ≤ 1) is below 1e-19 of the best point's (a
#: varies 24-fold over the radii), so the 6272 points of a lattice cannot add 1e-14 to any
#: sum; evaluating exp and log for each of them took half the kernel's time.
NEGLIGIBLE_COST = 90.0


@numba.njit(**_JIT)
def posterior_mean(
    rows, log_radius, family, step, xy, d, w2, centres, radius_power
):  # pragma: no cover
    """Posterior over profiles × centres, weights exp(−cost/2)·a^``radius_power`` where the
    force is positive (cost: the weighted squared residual at the non-negative optimal force;
    a: the contact radius; the tabulated radii are log-spaced, so power 0 is a prior uniform
    in log a, 1 one uniform in a): (mass, mean log F, mean x, mean y [m], mean log a, family
    of most mass); mass 0.0 when no force is positive.

    ``rows`` (J, P): the responses of P profiles (:meth:`RoundTables.profile_rows`) at
    distances j·``step``, distance-major so that one taxel's look-ups over every profile are
    contiguous (the innermost loop, which the compiler vectorises); ``log_radius`` (P,) and
    ``family`` (P,) name each profile. ``centres`` (L, 2) [m]."""
    n_j, n_p = rows.shape
    n_c = centres.shape[0]
    dd = 0.0
    for i in range(xy.shape[0]):
        dd += w2[i] * d[i] * d[i]
    cost = np.empty((n_c, n_p))
    force = np.empty((n_c, n_p))
    num = np.empty(n_p)
    den = np.empty(n_p)
    best = np.inf
    for c in range(n_c):
        num[:] = 0.0
        den[:] = 0.0
        for i in range(xy.shape[0]):
            dx = centres[c, 0] - xy[i, 0]
            dy = centres[c, 1] - xy[i, 1]
            v = math.sqrt(dx * dx + dy * dy) / step
            if v > n_j - 1:
                continue
            a = min(int(v), n_j - 2)
            wr = v - a
            wd = w2[i] * d[i]
            wi = w2[i]
            for p in range(n_p):
                lo = rows[a, p]
                val = lo + wr * (rows[a + 1, p] - lo)
                num[p] += wd * val
                den[p] += wi * val * val
        for p in range(n_p):
            if den[p] <= 0.0 or num[p] <= 0.0:
                force[c, p] = 0.0
            else:
                force[c, p] = num[p] / den[p]
                cost[c, p] = dd - force[c, p] * num[p]
                if cost[c, p] < best:
                    best = cost[c, p]
    if best == np.inf:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0
    n_f = 0
    for p in range(n_p):
        n_f = max(n_f, family[p] + 1)
    mass = np.zeros(n_f)
    log_f = x = y = log_a = 0.0
    for c in range(n_c):
        for p in range(n_p):
            if force[c, p] > 0.0 and cost[c, p] - best < NEGLIGIBLE_COST:
                w = math.exp(radius_power * log_radius[p] - 0.5 * (cost[c, p] - best))
                mass[family[p]] += w
                log_f += w * math.log(force[c, p])
                x += w * centres[c, 0]
                y += w * centres[c, 1]
                log_a += w * log_radius[p]
    total = mass.sum()
    most = 0
    for f in range(n_f):
        if mass[f] > mass[most]:
            most = f
    return total, log_f / total, x / total, y / total, log_a / total, most


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
    group,
    n_groups,
    radius_index,
    n_pre,
    pre,
    keep,
    iterations,
):
    """Best single contact: (cost, x, y, t, F, family); F = 0 when none has a positive force.

    ``centres`` (L, 2) [m] are lattices around the search's starts, ``group`` (L,) the start
    (0 … n_groups − 1) each belongs to. For every start, family and tabulated radius
    ``radius_index[m]``, the start's lattice centre of least cost is a candidate; the
    ``n_pre`` candidates of least lattice cost run ``pre`` Levenberg–Marquardt iterations,
    and the ``keep`` best of those run to ``iterations``.

    Why a candidate per radius, each from its own best centre: with precise readings a
    profile's basin is narrow in both (a 12 mm punch read by point taxels: within ≈ 5 % in
    radius and 0.3 mm in centre, or the run ends in a false valley), and the best centre
    moves with the radius. Why ranked by the lattice: the short runs cost most of the
    search; a lattice point costs one table look-up per taxel and profile. Why each start
    on its own: one lattice over all of them would give each radius a single centre.
    """
    n_f = table.shape[0]
    n_r = radius_index.shape[0]
    n_c = n_groups * n_f * n_r
    lattice = np.full(n_c, np.inf)
    lx = np.zeros(n_c)
    ly = np.zeros(n_c)
    costs, forces = _lattice_costs(table, t0, dt, step, xy, d, w2, centres, radius_index)
    for c in range(centres.shape[0]):
        for f in range(n_f):
            for m in range(n_r):
                q = (group[c] * n_f + f) * n_r + m
                if forces[f, m, c] > 0.0 and costs[f, m, c] < lattice[q]:
                    lattice[q] = costs[f, m, c]
                    lx[q] = centres[c, 0]
                    ly[q] = centres[c, 1]
    order = np.argsort(lattice)
    m = 0
    while m < min(n_pre, n_c) and lattice[order[m]] < np.inf:
        m += 1
    starts = np.empty((m, 4))
    for j in range(m):
        q = order[j]
        starts[j, 0] = lx[q]
        starts[j, 1] = ly[q]
        starts[j, 2] = t0 + dt * radius_index[q % n_r]
        starts[j, 3] = (q // n_r) % n_f
    return fit_from(table, t0, dt, step, xy, d, w2, starts, pre, keep, iterations)


@numba.njit(**_JIT)
def fit_near(  # pragma: no cover - compiled
    table,
    t0,
    dt,
    step,
    xy,
    d,
    w2,
    starts,
    offsets,
    reach,
    radius_index,
    n_pre,
    pre,
    keep,
    iterations,
):
    """:func:`fit_one` on the taxels within ``reach`` [m] of any of ``starts`` (S, 2) [m],
    searched on the lattice ``offsets`` (L, 2) [m] around each start, and the best contact's
    prediction at every taxel: (found, (cost, x, y, t, F, family), prediction (N,)); found
    False when no taxel is that near. ``xy`` (N, 2) [m], ``d`` (N,) [m] and ``w2`` (N,)
    [1/m²] are every taxel's. The same operations as the Python steps it replaces
    (round_contact.fit_round_contact), in one call: those cost ≈ 0.1 ms a search.
    """
    n = xy.shape[0]
    n_s = starts.shape[0]
    local = np.zeros(n, np.bool_)
    for i in range(n):
        if n_s == 1:
            dx, dy = xy[i, 0] - starts[0, 0], xy[i, 1] - starts[0, 1]
            local[i] = dx * dx + dy * dy <= reach * reach
        else:
            near2 = np.inf
            for j in range(n_s):
                dx, dy = xy[i, 0] - starts[j, 0], xy[i, 1] - starts[j, 1]
                near2 = min(near2, dx * dx + dy * dy)
            local[i] = math.sqrt(near2) <= reach
    m = int(local.sum())
    pred = np.zeros(n)
    none = (np.inf, 0.0, 0.0, 0.0, 0.0, -1)
    if m == 0:
        return False, none, pred
    lxy = np.empty((m, 2))
    ld = np.empty(m)
    lw2 = np.empty(m)
    q = 0
    for i in range(n):
        if local[i]:
            lxy[q, 0], lxy[q, 1] = xy[i, 0], xy[i, 1]
            ld[q], lw2[q] = d[i], w2[i]
            q += 1
    n_l = offsets.shape[0]
    centres = np.empty((n_s * n_l, 2))
    group = np.empty(n_s * n_l, np.int64)
    for j in range(n_s):
        for k in range(n_l):
            centres[j * n_l + k, 0] = starts[j, 0] + offsets[k, 0]
            centres[j * n_l + k, 1] = starts[j, 1] + offsets[k, 1]
            group[j * n_l + k] = j
    best = fit_one(
        table, t0, dt, step, lxy, ld, lw2, centres, group, n_s, radius_index, n_pre, pre, keep,
        iterations,
    )  # fmt: skip
    if best[4] > 0.0:
        pred = predict(table, best[5], t0, dt, step, xy, best[1], best[2], best[3], best[4])
    return True, best, pred


@numba.njit(**_JIT)
def fit_from(table, t0, dt, step, xy, d, w2, starts, pre, keep, iterations):  # pragma: no cover
    """Best single contact from the starts (N, 4) (x [m], y [m], log radius t, family): ``pre``
    Levenberg–Marquardt iterations from each, the ``keep`` lowest then to ``iterations``;
    (cost, x, y, t, F, family) as :func:`fit_one`."""
    n_s = starts.shape[0]
    cand = np.full((max(n_s, 1), 5), np.inf)
    fam = np.zeros(max(n_s, 1), np.int64)
    n = 0
    for j in range(n_s):
        f = int(starts[j, 3])
        cost, x, y, tt, force = lm_fit(
            table, f, t0, dt, step, xy, d, w2, starts[j, 0], starts[j, 1], starts[j, 2], pre
        )
        if force > 0.0:
            cand[n, 0] = cost
            cand[n, 1] = x
            cand[n, 2] = y
            cand[n, 3] = tt
            cand[n, 4] = force
            fam[n] = f
            n += 1
    best = (np.inf, 0.0, 0.0, 0.0, 0.0, -1)
    ranked = np.argsort(cand[:n, 0])
    for m in range(min(keep, n)):
        q = ranked[m]
        cost, x, y, t, force = lm_fit(
            table,
            fam[q],
            t0,
            dt,
            step,
            xy,
            d,
            w2,
            cand[q, 1],
            cand[q, 2],
            cand[q, 3],
            iterations,
        )
        if force > 0.0 and cost < best[0]:
            best = (cost, x, y, t, force, fam[q])
    return best


@numba.njit(**_JIT)
def render(centres, cell, sub, x, y, a, force, punch, out):  # pragma: no cover - compiled
    """Add one round contact's pressure [Pa] to ``out`` (N,) on square cells of side ``cell``
    [m] at ``centres`` (N, 2): the profile's mean over sub × sub points per cell, scaled so the
    cells carry ``force`` [N]. Profile (a² − r²)^(−½) when ``punch``, else (a² − r²)^(½); the
    punch's integrable edge singularity is sampled half a sub-cell inside the edge."""
    edge = a - 0.5 * cell / sub
    near = np.empty(centres.shape[0], np.int64)
    vals = np.empty(centres.shape[0])
    n = 0
    total = 0.0
    for c in range(centres.shape[0]):
        cx = centres[c, 0] - x
        cy = centres[c, 1] - y
        if math.sqrt(cx * cx + cy * cy) > a + cell:
            continue
        acc = 0.0
        for i in range(sub):
            px = cx + ((i + 0.5) / sub - 0.5) * cell
            for j in range(sub):
                py = cy + ((j + 0.5) / sub - 0.5) * cell
                r = math.sqrt(px * px + py * py)
                if r >= a:
                    continue
                rr = max(min(r, edge), 0.0)
                acc += 1.0 / math.sqrt(a * a - rr * rr) if punch else math.sqrt(a * a - rr * rr)
        near[n] = c
        vals[n] = acc / (sub * sub)
        total += vals[n]
        n += 1
    total *= cell * cell
    scale = force / total if total > 0.0 else 0.0
    for m in range(n):
        out[near[m]] += vals[m] * scale


@numba.njit(**_JIT)
def round_jacobian(table, t0, dt, step, xy, contacts, h_xy, h_t):  # pragma: no cover
    """(K, 4·C) derivatives [m per unit] of the readings at ``xy`` (K, 2) [m] of round
    contacts ``contacts`` (C, 5): force [N], centre x, y [m], log radius, family; in each
    one's log force, x, y and log radius (central differences of steps ``h_xy`` [m], ``h_t``
    through :func:`predict`). Why central: a forward difference errs by h/2 of the second
    derivative, which beside a contact is large across the radial direction (R'(r)/r): 14 %
    of the y column's largest entry at a taxel 0.7 mm from a 2 mm sphere's centre."""
    k = xy.shape[0]
    out = np.empty((k, 4 * contacts.shape[0]))
    for c in range(contacts.shape[0]):
        force, x, y, t = contacts[c, 0], contacts[c, 1], contacts[c, 2], contacts[c, 3]
        f = int(contacts[c, 4])
        base = predict(table, f, t0, dt, step, xy, x, y, t, force)
        xp = predict(table, f, t0, dt, step, xy, x + h_xy, y, t, force)
        xm = predict(table, f, t0, dt, step, xy, x - h_xy, y, t, force)
        yp = predict(table, f, t0, dt, step, xy, x, y + h_xy, t, force)
        ym = predict(table, f, t0, dt, step, xy, x, y - h_xy, t, force)
        tp = predict(table, f, t0, dt, step, xy, x, y, t + h_t, force)
        tm = predict(table, f, t0, dt, step, xy, x, y, t - h_t, force)
        for i in range(k):
            out[i, 4 * c] = base[i]
            out[i, 4 * c + 1] = (xp[i] - xm[i]) / (2.0 * h_xy)
            out[i, 4 * c + 2] = (yp[i] - ym[i]) / (2.0 * h_xy)
            out[i, 4 * c + 3] = (tp[i] - tm[i]) / (2.0 * h_t)
    return out
