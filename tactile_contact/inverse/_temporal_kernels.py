"""Compiled per-frame step of :class:`tactile_contact.inverse.temporal.FrameFusion` (numba,
cached on disk after the first call).

One pass over a frame's K readings: standardised residuals against the window's mean, the
three change statistics, the robust noise scale, and — when nothing changed — the frame added
to the window's ring buffer. A held or idle patch-frame costs this call and little Python
around it. Nothing here validates its arguments: :mod:`tactile_contact.inverse.temporal` does.
"""

from __future__ import annotations

import math

import numba
import numpy as np

# Re-exported for FrameFusion. It lives beside predict, which it calls: numba invalidates a
# cached kernel when its own file changes, not when a callee's does, and a stale copy of
# predict compiled into a kernel of this file took every bundle down
# ("NRT_adapt_ndarray_to_python: descr is NULL") after _round_kernels.py changed.
from tactile_contact.inverse._round_kernels import round_jacobian  # noqa: F401

_JIT = {"cache": True, "nogil": True}
#: The quiet path's kernels (an idle or held patch-frame): numpy's error model, i.e. no
#: division-by-zero test before each division (which kept LLVM from vectorising their
#: loops; ≈ 25 % of the idle scan). Their divisors are never 0 (σ > 0, frames ≥ 1, χ²
#: limits > 0, the converter's C0 + ΔC > 0 where a reading is used); the results are the
#: same IEEE divisions, bit for bit.
_QUIET_JIT = {**_JIT, "error_model": "numpy"}

#: The robust scale: the mean of the smallest TRIM share of the squared residuals, over that
#: mean for a standard normal (E[Z²; |Z| < z₀.₉₅]/0.9). Not the median: on whole-count
#: readings the squared residuals take a few values, and their median read 0.2–1.4 × the true
#: variance at 0.5-count noise, this 0.96–1.09.
TRIM = 0.9
TRIMMED_CHI2_1 = 0.623015484134684

# Slots of the state vector shared with temporal.FrameFusion.
N, HEAD, SCALE2, SCALE_FLOOR, SCALE_SEEN, SCALE_MEMORY, SCALE_PRIOR = range(7)
STATE_SIZE = 7


@numba.njit(**_QUIET_JIT)
def held_step(
    d, ok, window_ok, sigma, buf, total, state, nbr, local_limit, q, limits
):  # pragma: no cover - compiled
    """Test one frame against the held window and add it when nothing changed.

    Args:
        d: (K,) readings [m] (0 where not ``ok``).
        ok: (K,) the frame's valid taxels; window_ok: (K,) the window's.
        sigma: (K,) noise of one frame [m].
        buf: (H, K) ring buffer of the window's frames; total: (K,) their sum.
        state: float64 vector (slots above): frames in the window, next ring row, the scale²
            of the frame-to-frame scatter against sigma (the floor the tests use, frames it
            learnt from, its memory, the frames its starting value counts for).
        nbr: (K, W) each taxel's neighbourhood (indices; K pads); local_limit: (K,) χ²
            limits of the neighbourhood sums.
        q: (K, m) orthonormal whitened directions of the last result's parameters (m may be 0).
        limits: [χ² limit of the whole frame, χ² limit of the projection on q].

    Returns:
        0: unchanged, the frame added; 1: the whole frame changed; 2: a neighbourhood changed;
        3: the projection on the result's parameters changed; 4: the frame's valid taxels
        are not the window's (nothing added for 1–4).
    """
    k = d.shape[0]
    n = state[N]
    spread = math.sqrt(1.0 + 1.0 / n)
    u = np.zeros(k + 1)
    u2 = np.empty(k)
    m = 0
    whole = 0.0
    for i in range(k):
        if ok[i] != window_ok[i]:
            return 4
        if ok[i]:
            r = (d[i] - total[i] / n) / (sigma[i] * spread)
            u[i] = r
            u2[m] = r * r
            whole += r * r
            m += 1
    # How much of sigma changes from frame to frame (scale² of the scatter about the mean),
    # learnt from every frame, robustly (a moving contact changes a few taxels; the trimmed
    # mean leaves them out), faster while it has seen few frames.
    seen = state[SCALE_SEEN] + 1.0
    state[SCALE_SEEN] = seen
    rate = max(1.0 / (seen + state[SCALE_PRIOR]), 1.0 / state[SCALE_MEMORY])
    if m > 0:
        low = np.sort(u2[:m])[: max(int(TRIM * m), 1)]
        robust = low.mean() / TRIMMED_CHI2_1
        state[SCALE2] += rate * (robust - state[SCALE2])
    scale2 = max(state[SCALE2], state[SCALE_FLOOR])
    if whole > limits[0] * scale2:
        return 1
    for j in range(k):
        s = 0.0
        for w in range(nbr.shape[1]):
            v = u[nbr[j, w]]
            s += v * v
        if s > local_limit[j] * scale2:
            return 2
    if q.shape[1] > 0:
        proj = 0.0
        for c in range(q.shape[1]):
            g = 0.0
            for i in range(k):
                g += q[i, c] * u[i]
            proj += g * g
        if proj > limits[1] * scale2:
            return 3
    h = buf.shape[0]
    row = int(state[HEAD])
    full = n >= h
    for i in range(k):
        x = d[i] if ok[i] else 0.0
        if full:
            total[i] += x - buf[row, i]
        else:
            total[i] += x
        buf[row, i] = x
    if not full:
        state[N] = n + 1.0
    state[HEAD] = float((row + 1) % h)
    return 0


@numba.njit(**_JIT)
def idle_scan(buf, state, ok, sigma, nbr, limit, windows, quantised):  # pragma: no cover
    """The window length worth a detector pass on an idle patch, or 0.

    For each length w in ``windows`` (increasing, at most the frames held): the mean of the
    newest w frames, whitened by its noise (σ_i over √(effective frames), as
    temporal.FrameFusion.effective_frames), and each neighbourhood's
    energy Σ x_i² against ``limit`` (K,) (a χ² level that noise alone exceeds rarely). A light
    press held still concentrates its signal on a few taxels, and the energy of its mean grows
    with the frames it fills: the length whose energy exceeds its limit by the most is
    returned, so the detector runs on the mean that shows the press best, not every frame.
    """
    h, k = buf.shape
    n = int(state[N])
    head = int(state[HEAD])
    acc = np.zeros(k)
    x = np.zeros(k + 1)
    best, best_w = 1.0, 0
    done = 0
    s2 = max(state[SCALE2], 1e-12)
    for wi in range(windows.shape[0]):
        w = int(windows[wi])
        if w > n:
            break
        while done < w:
            row = (head - 1 - done) % h
            for i in range(k):
                acc[i] += buf[row, i]
            done += 1
        eff = w / s2 if not quantised else 1.0 / (max(1.0 - s2, 0.0) + s2 / w)
        g = math.sqrt(eff)
        for i in range(k):
            x[i] = acc[i] / w * g / sigma[i] if ok[i] else 0.0
        for j in range(k):
            s = 0.0
            for c in range(nbr.shape[1]):
                v = x[nbr[j, c]]
                s += v * v
            r = s / limit[j]
            if r > best:
                best, best_w = r, w
    return best_w


@numba.njit(**_JIT)
def window_sums(buf, state, windows, wsum):  # pragma: no cover - compiled
    """``wsum[j]`` (K,): the sum of the newest min(windows[j], frames held) frames of the ring
    ``buf``, added newest first (the sums idle_scan used to make every frame, bit for bit)."""
    h, k = buf.shape
    n = int(state[N])
    head = int(state[HEAD])
    acc = np.zeros(k)
    done = 0
    for wi in range(windows.shape[0]):
        w = min(int(windows[wi]), n)
        while done < w:
            row = (head - 1 - done) % h
            for i in range(k):
                acc[i] += buf[row, i]
            done += 1
        for i in range(k):
            wsum[wi, i] = acc[i]


@numba.njit(**_QUIET_JIT)
def held_step_sums(
    d, ok, window_ok, sigma, buf, total, state, nbr, local_limit, q, limits, wsum, windows, spare
):  # pragma: no cover - compiled
    """:func:`held_step`, and when the frame joins the window, the idle windows' sums
    ``wsum`` (:func:`window_sums`) kept: each gains the frame and loses the one that leaves
    its newest ``windows[j]``. Why: the idle scan read up to 32 rows of the window every idle
    frame, and with a robot's 34 windows through the cache that was most of a quiet frame's
    compiled time. ``spare`` (K,): scratch for the row the frame overwrites."""
    h, k = buf.shape
    n = int(state[N])
    row = int(state[HEAD])
    if windows.shape[0] and windows[windows.shape[0] - 1] >= h:
        for i in range(k):
            spare[i] = buf[row, i]
    code = held_step(d, ok, window_ok, sigma, buf, total, state, nbr, local_limit, q, limits)
    if code == 0:
        for wi in range(windows.shape[0]):
            w = int(windows[wi])
            if n >= w:
                old = (row - w) % h
                for i in range(k):
                    leaving = spare[i] if old == row else buf[old, i]
                    wsum[wi, i] += buf[row, i] - leaving
            else:
                for i in range(k):
                    wsum[wi, i] += buf[row, i]
    return code


@numba.njit(**_QUIET_JIT)
def idle_scan_sums(wsum, state, ok, sigma, nbr, limit, windows, quantised):  # pragma: no cover
    """:func:`idle_scan` on the windows' kept sums ``wsum`` (:func:`held_step_sums`) instead
    of the ring's rows: the same statistics (up to the sums' rounding), the same answer."""
    k = wsum.shape[1]
    n = int(state[N])
    x = np.zeros(k + 1)
    best, best_w = 1.0, 0
    s2 = max(state[SCALE2], 1e-12)
    for wi in range(windows.shape[0]):
        w = int(windows[wi])
        if w > n:
            break
        eff = w / s2 if not quantised else 1.0 / (max(1.0 - s2, 0.0) + s2 / w)
        g = math.sqrt(eff)
        for i in range(k):
            x[i] = wsum[wi, i] / w * g / sigma[i] if ok[i] else 0.0
        for j in range(k):
            s = 0.0
            for c in range(nbr.shape[1]):
                v = x[nbr[j, c]]
                s += v * v
            # r = s / limit[j] > best ≥ 1 needs s > limit[j] (a correctly rounded division
            # is monotone): the division, for the few that may pass. Why: three divisions an
            # element a window were most of the scan (the same answer, bit for bit).
            if s > limit[j]:
                r = s / limit[j]
                if r > best:
                    best, best_w = r, w
    return best_w


@numba.njit(**_JIT)
def orthonormal(a, ok, sigma, q):  # pragma: no cover - compiled
    """The columns of ``a`` (K, m) over ``sigma`` (K,) at the ``ok`` taxels (0 elsewhere),
    orthonormalised into ``q`` (K, m) by modified Gram–Schmidt; columns that add less than
    1e-9 of their norm are dropped. Returns the columns kept (the first ones of q)."""
    k, m = a.shape
    kept = 0
    for j in range(m):
        v = np.zeros(k)
        norm0 = 0.0
        for i in range(k):
            if ok[i]:
                v[i] = a[i, j] / sigma[i]
                norm0 += v[i] * v[i]
        for c in range(kept):
            dot = 0.0
            for i in range(k):
                dot += q[i, c] * v[i]
            for i in range(k):
                v[i] -= dot * q[i, c]
        norm = 0.0
        for i in range(k):
            norm += v[i] * v[i]
        if norm0 == 0.0 or norm <= 1e-18 * norm0:
            continue
        s = 1.0 / math.sqrt(norm)
        for i in range(k):
            q[i, kept] = v[i] * s
        kept += 1
    return kept


@numba.njit(**_JIT)
def best_split(buf, state, total, sigma, q):  # pragma: no cover - compiled
    """(old frames k, χ² statistic) of the most likely step in the window along ``q``
    (K, m): for every split of the n frames into the k oldest and the rest, k(n−k)/n·‖ȳ_new −
    ȳ_old‖², y the frames' whitened projections on q (σ ``sigma`` (K,))."""
    h, kk = buf.shape
    n = int(state[N])
    head = int(state[HEAD])
    m = q.shape[1]
    y = np.zeros((n, m))
    for j in range(n):
        row = (head - n + j) % h
        for i in range(kk):
            r = (buf[row, i] - total[i] / n) / sigma[i]
            if r != 0.0:
                for c in range(m):
                    y[j, c] += q[i, c] * r
    run = np.zeros(m)
    tot = np.zeros(m)
    for j in range(n):
        for c in range(m):
            tot[c] += y[j, c]
    best, best_k = -1.0, 0
    for k in range(1, n):
        s = 0.0
        for c in range(m):
            run[c] += y[k - 1, c]
            d = run[c] / k - (tot[c] - run[c]) / (n - k)
            s += d * d
        stat = k * (n - k) / n * s
        if stat > best:
            best, best_k = stat, k
    return best_k, best


@numba.njit(**_QUIET_JIT)
def quiet_frame(
    dc,
    status,
    perm,
    unusable,
    convert,
    delta,
    ok,
    window_ok,
    sigma,
    buf,
    total,
    state,
    nbr,
    local_limit,
    q,
    limits,
    scan,
    trigger_limit,
    windows,
    wsum,
    spare,
):  # pragma: no cover - compiled
    """A batch's patch-frame taken straight to the fusion's held step, in one call (what an
    idle or held patch-frame costs: contact_reconstruction's PatchPipeline).

    Args:
        dc: (K,) the message's ΔC [F] (any float type), status: (K,) its status flags, both
            in the message's taxel order; perm: (K,) the message's index of each bundle
            taxel; unusable: the status flags that leave a taxel out.
        convert: [h [m], ε0·εr·A [F·m], C0 [F], full scale [F]]
            (inverse.readings.ReadingModel).
        delta, ok: (K,) filled with the frame's δ [m] and taxels used, as
            ReadingModel.from_delta_c gives them for ΔC where the status allows, 0 elsewhere.
        window_ok … limits: held_step's arguments.
        scan: run the idle scan (quantised readings) when nothing changed; trigger_limit,
            windows: its arguments; wsum, spare: held_step_sums' (the windows' sums kept).

    Returns:
        (code, window, valid): code -1 if a reading is not finite (nothing converted, the
        fusion untouched: the caller's full path says so), else held_step's answer; the
        idle scan's window (-1: not run); taxels whose status allows them.
    """
    k = perm.shape[0]
    for i in range(k):
        if not math.isfinite(dc[perm[i]]):
            return -1, -1, 0
    h, eps_area, rest_c, full_scale = convert[0], convert[1], convert[2], convert[3]
    valid = 0
    for i in range(k):
        j = perm[i]
        x = float(dc[j])
        good = (status[j] & unusable) == 0
        valid += good
        good = good and x > -rest_c and abs(x) <= full_scale
        ok[i] = good
        delta[i] = x * (h * h) / (eps_area + x * h) if good else 0.0
    code = held_step_sums(
        delta,
        ok,
        window_ok,
        sigma,
        buf,
        total,
        state,
        nbr,
        local_limit,
        q,
        limits,
        wsum,
        windows,
        spare,
    )
    w = -1
    if code == 0 and scan:
        w = idle_scan_sums(wsum, state, window_ok, sigma, nbr, trigger_limit, windows, True)
    return code, w, valid


@numba.njit(**_QUIET_JIT)
def learn_noise(d, ok, sigma, var, m4, alpha, spike):  # pragma: no cover - compiled
    """NoiseTracker.update's step (inverse.detection): False (nothing learnt) if a used
    reading (``ok`` and finite) exceeds ``spike``·σ; else, at the used taxels,
    var += α(δ² − var) and m4 += α(δ⁴ − m4) (the same floating-point operations, in the same
    order, as numpy's). Here, not in detection.py, so that quiet_batch may call it (a cached
    kernel calls only kernels of its own file); detection's tracker uses this one."""
    n = d.shape[0]
    for i in range(n):
        x = d[i]
        if ok[i] and math.isfinite(x) and abs(x) > spike * sigma[i]:
            return False
    for i in range(n):
        x = d[i]
        if ok[i] and math.isfinite(x):
            x2 = x * x
            var[i] += alpha * (x2 - var[i])
            m4[i] += alpha * (x2 * x2 - m4[i])
    return True


#: quiet_batch's arrays of one patch (its slot s) in its typed lists: F1 float vectors at
#: f1[F1·s + j], I1 integer vectors, F2 float matrices, B1 bool vectors (the slots' order).
(
    F1_CONVERT,
    F1_DELTA,
    F1_SIGMA,
    F1_TOTAL,
    F1_STATE,
    F1_LOCAL,
    F1_LIMITS,
    F1_TRIGGER,
    F1_SPARE,
    F1_NOISE_SIGMA,
    F1_NOISE_VAR,
    F1_NOISE_M4,
    F1_NOISE_RATE,
) = range(13)
F1 = 13
I1_PERM, I1_WINDOWS = range(2)
I1 = 2
F2_BUF, F2_Q, F2_WSUM = range(3)
F2 = 3
B1_OK, B1_WINDOW_OK = range(2)
B1 = 2
#: quiet_batch's table, a row a patch: what it is given (IN_*), what it answers (OUT_*).
IN_START, IN_END, IN_SLOT, IN_SCAN, IN_IDLE, IN_EXPECT = range(6)
OUT_CODE, OUT_WINDOW, OUT_VALID, OUT_FAST, OUT_LEARNT = range(6, 11)
TABLE = 11


@numba.njit(**_QUIET_JIT)
def quiet_batch(dc, status, unusable, table, f1, i1, f2, i2, b1):  # pragma: no cover - compiled
    """:func:`quiet_frame` for each of a batch's quiet patches in one call (contact_
    reconstruction's ContactBatches: an idle patch-frame's Python was most of its cost), and
    for those nothing further happens to, the noise tracker's step too.

    Args:
        dc, status: the batch's ΔC [F] and status flags, every patch's rows one after the
            other (the message's arrays).
        unusable: the status flags that leave a taxel out.
        table: (P, TABLE) int64, a row a patch. Given: IN_START, IN_END its first row of
            ``dc`` and the row after its last (a message may carry taxels its bundle lacks:
            disabled ones); IN_SLOT its slot in the typed lists f1, i1, f2, i2 (nbr), b1
            (layout: the F1_*, I1_*, F2_*, B1_* constants; its fusion's and its noise
            tracker's own arrays, changed in place as quiet_frame and learn_noise change
            them); IN_SCAN run the idle scan (FrameFusion.scan_due of an idle result);
            IN_IDLE the held result has no contact (the noise tracker learns from the
            frame); IN_EXPECT the held result's taxels used. Filled: OUT_CODE, OUT_WINDOW,
            OUT_VALID quiet_frame's code, scan window and valid count; OUT_FAST whether
            nothing more happens (unchanged, the valid count the result's, the scan picked
            nothing; left as given, -1, for a patch not reached); OUT_LEARNT whether the
            tracker learnt from it (fast idle patches only).
    """
    for p in range(table.shape[0]):
        s = table[p, IN_SLOT]
        a, e = table[p, IN_START], table[p, IN_END]
        scan = table[p, IN_SCAN] != 0
        perm = i1[I1 * s + I1_PERM]
        x = F1 * s
        delta = f1[x + F1_DELTA]
        ok = b1[B1 * s + B1_OK]
        code, w, valid = quiet_frame(
            dc[a:e],
            status[a:e],
            perm,
            unusable,
            f1[x + F1_CONVERT],
            delta,
            ok,
            b1[B1 * s + B1_WINDOW_OK],
            f1[x + F1_SIGMA],
            f2[F2 * s + F2_BUF],
            f1[x + F1_TOTAL],
            f1[x + F1_STATE],
            i2[s],
            f1[x + F1_LOCAL],
            f2[F2 * s + F2_Q],
            f1[x + F1_LIMITS],
            scan,
            f1[x + F1_TRIGGER],
            i1[I1 * s + I1_WINDOWS],
            f2[F2 * s + F2_WSUM],
            f1[x + F1_SPARE],
        )
        fast = code == 0 and valid == table[p, IN_EXPECT] and (not scan or w == 0)
        learnt = False
        if fast and table[p, IN_IDLE] != 0:
            rate = f1[x + F1_NOISE_RATE]
            learnt = learn_noise(
                delta,
                ok,
                f1[x + F1_NOISE_SIGMA],
                f1[x + F1_NOISE_VAR],
                f1[x + F1_NOISE_M4],
                rate[0],
                rate[1],
            )
        table[p, OUT_CODE] = code
        table[p, OUT_WINDOW] = w
        table[p, OUT_VALID] = valid
        table[p, OUT_FAST] = fast
        table[p, OUT_LEARNT] = learnt


# quiet_batch's typed lists are made and changed here, compiled and cached: from Python,
# numba.typed.List compiles its methods in every new process (≈ 1 s a list type, a worker's
# first batch held for seconds).
@numba.njit(**_JIT)
def list_of(a):  # pragma: no cover - compiled
    """A typed list holding ``a``."""
    out = numba.typed.List()
    out.append(a)
    return out


@numba.njit(**_JIT)
def list_add(lst, a):  # pragma: no cover - compiled
    """``a`` appended to the typed list ``lst``."""
    lst.append(a)


@numba.njit(**_JIT)
def list_set(lst, i, a):  # pragma: no cover - compiled
    """``lst[i] = a`` in the typed list ``lst``."""
    lst[i] = a
