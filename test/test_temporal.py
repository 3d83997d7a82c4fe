"""Frames of a held scene fused over time (Reconstructor(fuse=True), inverse/temporal.py).

Presses come from the independent fine forward model (tactile_contact.model.forward: exact
cell pressures on 0.25–0.5 mm cells, electrode quadrature), read as 8-bit whole counts with
0.5-count Gaussian converter noise before rounding — not from the fit's own tables. The
change statistics of the compiled step are checked against numpy written out here.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.stats import chi2

from tactile_contact.inverse import _temporal_kernels as kern
from tactile_contact.inverse.reconstruction import Reconstructor
from tactile_contact.inverse.round_contact import FAMILIES, RoundFit
from tactile_contact.inverse.temporal import FrameFusion, round_jacobian
from tactile_contact.model.indenters import FlatPunch, HertzSphere

NOISE = 0.5  # converter noise [counts RMS]


@pytest.fixture(scope="module")
def setup(fusion_setup):
    """The hexagon, its fine-model truth and one frame's noise (test/conftest.py)."""
    return fusion_setup


def counts(r, delta: np.ndarray, rng, n: int) -> np.ndarray:
    """n frames of ΔC [F]: whole counts of ``delta`` [m] with 0.5-count noise before rounding."""
    c = r.readings.counts(delta)
    return np.rint(c + rng.normal(0.0, NOISE, (n, len(c)))) * r.readings.lsb


PRESSES = [
    (HertzSphere(6e-3), 1.0, 30, (0.0, 0.0)),
    (HertzSphere(6e-3), 2.0, 41, (1.5e-3, 1.0e-3)),
    (HertzSphere(3e-3), 1.5, 30, (2.75e-3, 0.0)),
    (FlatPunch(1.5e-3), 1.0, 53, (0.0, 1.0e-3)),
    (HertzSphere(3e-3), 3.0, 17, (1.0e-3, -1.0e-3)),
]


def test_a_held_press_is_measured_better_the_longer_it_is_held(setup):
    """Ten frames of each press: the fused result after 10 frames errs far less than single
    frames do (median over presses and noise draws), its ``frames`` says what it fuses, and
    most frames are republished, not solved."""
    bundle, alone, truth, sigma = setup
    err1, err10 = [], []
    for seed in range(3):
        rng = np.random.default_rng(seed)
        for ind, force, taxel, off in PRESSES:
            where = alone.taxel_xy[taxel] + np.asarray(off)
            frames = counts(alone, truth.compression(ind, force, where), rng, 10)
            fused = Reconstructor.from_bundle(bundle, follow=True, fuse=True)
            for dc in frames:
                res = fused.solve(dc, noise=sigma)
                one = alone.solve(dc, noise=sigma)
                err1.append(abs(one.total_force / force - 1) if one.in_contact else 1.0)
            assert res.frames == 10 and fused.fusion.counts.solved == 1
            err10.append(abs(res.total_force / force - 1) if res.in_contact else 1.0)
    single, held = float(np.median(err1)), float(np.median(err10))
    assert held < 0.6 * single and held < 0.10, (single, held)


def test_the_first_frame_is_what_the_reconstructor_alone_gives(setup):
    bundle, alone, truth, sigma = setup
    fused = Reconstructor.from_bundle(bundle, fuse=True)
    rng = np.random.default_rng(7)
    (dc,) = counts(alone, truth.compression(HertzSphere(6e-3), 1.5, alone.taxel_xy[30]), rng, 1)
    a, b = alone.solve(dc, noise=sigma), fused.solve(dc, noise=sigma)
    assert b.frames == 1 and fused.fusion.last == "solved"
    for name in ("total_force", "cop", "contact_area", "peak_pressure", "solver", "contacts"):
        assert getattr(a, name) == getattr(b, name)
    assert np.array_equal(a.traction, b.traction) and np.array_equal(a.deflection, b.deflection)


def test_a_change_is_solved_at_once(setup):
    """A press that moves 1 mm, one that doubles, a release and a valid mask that changes are
    each solved on their own in the frame they happen."""
    bundle, r0, truth, sigma = setup
    r = Reconstructor.from_bundle(bundle, follow=True, fuse=True)
    rng = np.random.default_rng(3)
    ind, where = HertzSphere(6e-3), r0.taxel_xy[30]
    scenes = [
        (truth.compression(ind, 1.5, where), None),
        (truth.compression(ind, 1.5, where + np.array([1e-3, 0.0])), None),
        (truth.compression(ind, 3.0, where + np.array([1e-3, 0.0])), None),
        (np.zeros(r.n_taxels), None),
    ]
    valid = np.ones(r.n_taxels, bool)
    valid[5] = False
    scenes.append((np.zeros(r.n_taxels), valid))
    for d, ok in scenes:
        frames = counts(r, d, rng, 6)
        res = r.solve(frames[0], ok, noise=sigma)
        assert r.fusion.last == "solved" and res.frames == 1
        for dc in frames[1:]:
            res = r.solve(dc, ok, noise=sigma)
            assert r.fusion.last in ("held", "fused")
    changes = r.fusion.counts.changes
    assert sum(changes.values()) == 5 and changes["start"] == 1 and changes["valid"] == 1
    assert not res.in_contact


def test_a_press_too_light_for_one_frame_is_found_when_held(setup):
    """0.4 N between two taxels: no single frame of it reaches the detector's threshold; held
    for 24 frames (after 20 without contact), the patch's idle checks on the means of its
    last frames find it, and the frames before it began are dropped from the window."""
    bundle, alone, truth, sigma = setup
    where = (alone.taxel_xy[31] + alone.taxel_xy[35]) / 2
    clean = truth.compression(HertzSphere(3e-3), 0.4, where)
    for seed in (11, 12, 13):
        r = Reconstructor.from_bundle(bundle, follow=True, fuse=True)
        rng = np.random.default_rng(seed)
        press, idle = counts(alone, clean, rng, 24), counts(alone, 0 * clean, rng, 20)
        assert not any(alone.solve(dc, noise=sigma).in_contact for dc in press)
        for dc in idle:
            assert not r.solve(dc, noise=sigma).in_contact
        for dc in press:
            res = r.solve(dc, noise=sigma)
        assert res.in_contact and res.frames <= 24
        assert abs(res.total_force / 0.4 - 1) < 0.3
        # (Between two taxels a light press's centre slides along the line joining them: its
        # readings change little for millimetres; 1.9 mm off in one draw.)
        assert np.hypot(*(np.asarray(res.cop) - where)) < 2.5e-3


def test_a_light_press_is_found_soon_after_its_frames_suffice(setup):
    """0.4 N of a 12 mm sphere between two taxels after 30 frames without contact: its
    single-frame matched-filter statistic z₁ (noise-free, the detector's own bank) says how
    many frames a mean needs to clear the threshold; in ten draws the fusion reports it at
    most four frames later. (Windows of 4, 8, 16, 32 looked at every third frame, and a
    contact the look found solved again over the whole window, idle frames included: 9 and
    13 frames in two of these draws, the information sufficing from the 4th.)"""
    import copy

    bundle, alone, truth, sigma = setup
    where = (alone.taxel_xy[31] + alone.taxel_xy[35]) / 2
    clean = truth.compression(HertzSphere(6e-3), 0.4, where)
    det = copy.deepcopy(alone.detector)
    det.set_noise(sigma)
    need = math.ceil((det.threshold / det.statistic(clean)[0]) ** 2)
    assert 3 <= need <= 6  # (light enough that one frame does not find it)
    firsts = []
    for seed in range(10):
        r = Reconstructor.from_bundle(bundle, follow=True, fuse=True)
        rng = np.random.default_rng(seed)
        idle, press = counts(alone, 0 * clean, rng, 30), counts(alone, clean, rng, 20)
        for dc in idle:
            assert not r.solve(dc, noise=sigma).in_contact
        seen = [r.solve(dc, noise=sigma).in_contact for dc in press]
        firsts.append(seen.index(True) + 1 if any(seen) else 99)
    assert max(firsts) <= need + 4, (need, firsts)


def test_a_light_object_resting_near_the_threshold_is_not_looked_at_every_frame(setup):
    """A 0.18 N sphere of 12 mm held between two taxels for 1500 frames: its window stands out frame
    after frame and the detector finds it in some; after a look that finds nothing the next
    waits a few frames (IDLE_BACKOFF). Solves counted as the reconstructor's: 600-odd looked
    at every frame, ≈ 190 with the back-off; found in most frames either way."""
    bundle, alone, truth, sigma = setup
    where = (alone.taxel_xy[31] + alone.taxel_xy[35]) / 2
    clean = truth.compression(HertzSphere(6e-3), 0.18, where)
    frames = counts(alone, clean, np.random.default_rng(3), 1600)
    r = Reconstructor.from_bundle(bundle, follow=True, fuse=True)
    solves = [0]
    inner = r.fusion._solve

    def counted(*args):  # (the fusion's solve callback, counted)
        solves[0] += 1
        return inner(*args)

    r.fusion._solve = counted
    for dc in frames[:100]:
        r.solve(dc, noise=sigma)
    solves[0] = 0
    seen = sum(r.solve(dc, noise=sigma).in_contact for dc in frames[100:])
    assert solves[0] < 350, solves[0]
    assert seen > 300


def test_noise_alone_gives_no_contact_and_almost_no_solve(setup):
    """3000 frames of noise at the stated level: no contact, and the patch solves (the idle
    check) every IDLE_EVERY frames only."""
    bundle, alone, _, sigma = setup
    r = Reconstructor.from_bundle(bundle, fuse=True)
    frames = counts(alone, np.zeros(alone.n_taxels), np.random.default_rng(5), 3000)
    assert not any(r.solve(dc, noise=sigma).in_contact for dc in frames)
    c = r.fusion.counts
    assert c.solved <= 10 and c.held >= 0.7 * len(frames)


def test_unknown_noise_is_learnt_from_the_frames(setup):
    """Float readings with no noise level: the fusion's noise scale learns the readings'
    (0.2 µm, far below the sensor model's 4.3 µm), so a 0.2 mm step is a change."""
    bundle, alone, truth, _ = setup
    r = Reconstructor.from_bundle(bundle, follow=True, fuse=True)
    rng = np.random.default_rng(2)
    d = truth.compression(HertzSphere(6e-3), 1.5, alone.taxel_xy[30])
    for _ in range(40):
        r.solve_deflection(d + rng.normal(0.0, 0.2e-6, d.shape))
    scale = r.fusion.scatter * float(np.median(alone.default_noise))
    assert 0.15e-6 < scale < 0.3e-6
    moved = truth.compression(HertzSphere(6e-3), 1.5, alone.taxel_xy[30] + [2e-4, 0.0])
    r.solve_deflection(moved + rng.normal(0.0, 0.2e-6, d.shape))
    assert r.fusion.last == "solved"


def test_what_stays_from_frame_to_frame_is_not_averaged_away(setup):
    """An idle skin whose baselines sit at fixed fractions of a count (a driver's baseline
    is a mean of whole counts) with little converter noise: the frames barely scatter, so
    their mean is credited with about one frame's noise (the noise passed in, the RMS a
    tracker learns), and the idle checks on it (means of up to 32 frames) report no contact
    in 4000 frames. Credited with σ/√32, these offsets read as contacts."""
    bundle, alone, _, _ = setup
    r = Reconstructor.from_bundle(bundle, fuse=True)
    rng = np.random.default_rng(9)
    offset = rng.uniform(-0.5, 0.5, alone.n_taxels)
    counts_ = np.rint(rng.normal(0.0, 0.1, (4000, alone.n_taxels))) + offset
    frames = counts_ * alone.readings.lsb
    tracked = alone.readings.from_counts(np.sqrt(np.mean(counts_[:500] ** 2, axis=0)))
    tracked = np.maximum(tracked, alone.default_noise / np.sqrt(2.0))
    assert not any(r.solve(dc, noise=tracked).in_contact for dc in frames)
    assert r.fusion.scatter < 0.5 and r.fusion.effective_frames(8) < 1.5
    # Credited with all of it averaging out, the same means do read as contacts.
    means = frames.reshape(125, 32, -1).mean(axis=1)
    false = sum(alone.solve(m, noise=tracked / np.sqrt(32)).in_contact for m in means)
    assert false > 0


def test_effective_frames():
    f = FrameFusion(np.zeros((3, 2)), lambda *a: None, lambda *a: None)
    f._quantised = True
    for s2, n, want in ((1.0, 10, 10.0), (0.0, 10, 1.0), (4.0, 8, 2.0), (0.5, 5, 1 / 0.6)):
        f._state[kern.SCALE2] = s2
        assert f.effective_frames(n) == pytest.approx(want)
        assert f.effective_frames(1) == 1.0
    f._quantised = False
    f._state[kern.SCALE2] = 0.01
    assert f.effective_frames(4) == pytest.approx(400.0)


# --- the compiled step against numpy -----------------------------------------------------


def numpy_step(d, ok, sigma, frames, nbr, q, scale2):
    """The change statistics written out: whole frame, neighbourhoods, projection."""
    mean = np.mean(frames, axis=0)
    u = np.where(ok, (d - mean) / (sigma * math.sqrt(1 + 1 / len(frames))), 0.0)
    padded = np.append(u, 0.0)
    local = (padded[nbr] ** 2).sum(axis=1)
    proj = float(np.sum((q.T @ u) ** 2)) if q.shape[1] else 0.0
    return float(np.sum(u**2)) / scale2, local / scale2, proj / scale2


@given(
    seed=st.integers(0, 2**31 - 1),
    n=st.integers(1, 12),
    shift=st.floats(0.0, 4.0),
    window=st.integers(2, 8),
)
def test_held_step_matches_numpy_and_keeps_the_window_sum(seed, n, shift, window):
    rng = np.random.default_rng(seed)
    k = 20
    xy = rng.uniform(0, 0.02, (k, 2))
    fusion = FrameFusion(xy, lambda *a: None, lambda *a: None, window=window)
    ok = rng.random(k) > 0.1
    sigma = rng.uniform(0.5, 2.0, k)
    pushed = [np.where(ok, rng.normal(size=k), 0.0) for _ in range(n)]
    # The window as the fusion holds it: the last `window` frames pushed.
    buf, total = np.zeros((window, k)), np.zeros(k)
    state = np.zeros(kern.STATE_SIZE)
    state[kern.SCALE2], state[kern.SCALE_FLOOR], state[kern.SCALE_MEMORY] = 1.0, 1.0, 50.0
    buf[0], total[:] = pushed[0], pushed[0]
    state[kern.N], state[kern.HEAD] = 1.0, 1.0 % window
    never = np.full(2, np.inf)
    q = np.linalg.qr(rng.normal(size=(k, 3)))[0] * ok[:, None]
    for x in pushed[1:]:
        assert kern.held_step(x, ok, ok, sigma, buf, total, state, fusion._nbr,
                              fusion._local_limit * np.inf, q, never) == 0  # fmt: skip
    held = pushed[-window:]
    assert state[kern.N] == len(held)
    assert np.allclose(total, np.sum(held, axis=0))
    d = np.where(ok, rng.normal(size=k) + shift, 0.0)
    scale_before = state[kern.SCALE2]
    whole, local, proj = numpy_step(d, ok, sigma, held, fusion._nbr, q, scale_before)
    # Each test alone at a limit just below / above its statistic.
    for which, stat in ((0, whole), (1, local.max()), (2, proj)):
        lim = np.full(2, np.inf)
        local_lim = fusion._local_limit * np.inf
        for below in (True, False):
            s = state.copy()
            s[kern.SCALE_SEEN] = s[kern.SCALE_MEMORY] = 1e15  # the scale kept as it is
            s[kern.SCALE_FLOOR] = 0.0
            f = 0.999 if below else 1.001
            if which == 0:
                lim = np.array([stat * f, np.inf])
            elif which == 1:
                local_lim = np.where(np.isclose(local, stat), local * f, np.inf)
            else:
                lim = np.array([np.inf, stat * f])
            got = kern.held_step(d, ok, ok, sigma, buf.copy(), total.copy(), s, fusion._nbr,
                                 local_lim, q, lim)  # fmt: skip
            assert got == ((which + 1) if below else 0)
            lim, local_lim = np.full(2, np.inf), fusion._local_limit * np.inf


def test_limits_are_the_chi2_quantiles(setup):
    _, r, _, _ = setup
    f = FrameFusion(r.taxel_xy, lambda *a: None, lambda *a: None, alpha=1e-3)
    sizes = (f._nbr < r.n_taxels).sum(axis=1)
    assert np.allclose(f._local_limit, chi2.isf(1e-3 / r.n_taxels, sizes))
    assert sizes.min() >= 3 and sizes.max() <= 9  # itself and its ring at 5.5 mm


def test_round_jacobian_against_central_differences(setup):
    _, r, _, _ = setup
    from tactile_contact.inverse.summary import Contact

    c = Contact(1.2, (float(r.taxel_xy[30, 0]) + 7e-4, float(r.taxel_xy[30, 1])), 2e-3, "hertz")
    jac = round_jacobian(r._round, r.taxel_xy, (c,))
    fam = FAMILIES.index("hertz")

    def reading(force, x, y, radius):
        return r._round.predict(RoundFit(force, (x, y), fam, radius, 0.0), r.taxel_xy)

    base = reading(c.force, *c.center, c.radius)
    assert np.allclose(jac[:, 0], base)  # ∂/∂ log F of F·R is F·R
    h = 2e-5
    x, y = c.center
    dx = (reading(c.force, x + h, y, c.radius) - reading(c.force, x - h, y, c.radius)) / (2 * h)
    scale = np.abs(dx).max()
    # (central differences both: they agree to the steps' h², not to a forward one's h)
    assert np.abs(jac[:, 1] - dx).max() < 0.02 * scale
    dy = (reading(c.force, x, y + h, c.radius) - reading(c.force, x, y - h, c.radius)) / (2 * h)
    assert np.abs(jac[:, 2] - dy).max() < 0.02 * np.abs(dy).max()
    t = 0.03
    grown, shrunk = (reading(c.force, x, y, c.radius * math.exp(s)) for s in (t, -t))
    da = (grown - shrunk) / (2 * t)
    assert np.abs(jac[:, 3] - da).max() < 0.02 * np.abs(da).max()
    # Two contacts: each one's four columns, in order, as it alone gives them.
    other = Contact(0.7, (float(r.taxel_xy[50, 0]), float(r.taxel_xy[50, 1]) - 9e-4), 3e-3, "punch")
    both = round_jacobian(r._round, r.taxel_xy, (c, other))
    assert both.shape == (len(r.taxel_xy), 8)
    np.testing.assert_allclose(both[:, :4], jac, rtol=1e-12, atol=1e-18)
    alone = round_jacobian(r._round, r.taxel_xy, (other,))
    np.testing.assert_allclose(both[:, 4:], alone, rtol=1e-12, atol=1e-18)
    assert np.abs(alone[:, 2]).max() > 0.1 * np.abs(alone[:, 0]).max()  # (its y matters)
    field = Contact(1.0, (0.0, 0.0), 1e-3, "field")
    assert round_jacobian(r._round, r.taxel_xy, (field,)) is None


def test_warm_up_compiles_the_step_and_leaves_no_state(setup):
    """In a fresh interpreter (compiled signatures are process-wide): after warm_up, every
    compiled kernel of the fusion is built, and the fusion holds no frame of it."""
    import json
    import subprocess
    import sys
    import textwrap

    bundle = setup[0]
    script = textwrap.dedent(
        """
        import json, sys
        from tactile_contact.inverse import _temporal_kernels as kern
        from tactile_contact.inverse.reconstruction import Reconstructor
        r = Reconstructor.from_bundle(sys.argv[1], fuse=True)
        r.warm_up()
        f = r.fusion
        names = ("held_step", "idle_scan", "best_split", "orthonormal", "round_jacobian")
        built = all(len(getattr(kern, name).signatures) >= 1 for name in names)
        print(json.dumps([built, f.result is None, f.frames]))
        """
    )
    out = subprocess.run(
        [sys.executable, "-c", script, str(bundle)], capture_output=True, text=True, check=True
    )
    built, empty, frames = json.loads(out.stdout.strip().splitlines()[-1])
    assert built and empty and frames == 0


@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 40), bump=st.floats(0.0, 3.0))
def test_idle_scan_matches_numpy(seed, n, bump):
    """The window the idle scan picks: the length (of 4, 8, 16, 32 held) whose mean's
    neighbourhood energy, whitened by its noise, exceeds its limit by the most; 0 if none."""
    rng = np.random.default_rng(seed)
    k, window = 20, 32
    xy = rng.uniform(0, 0.02, (k, 2))
    fusion = FrameFusion(xy, lambda *a: None, lambda *a: None, window=window)
    ok = rng.random(k) > 0.1
    sigma = rng.uniform(0.5, 2.0, k)
    rows = rng.normal(size=(n, k)) + bump * (np.arange(n)[:, None] >= n // 2) * (xy[:, :1].T > 0.01)
    rows = np.where(ok, rows, 0.0)
    held = rows[-window:]
    buf = np.zeros((window, k))
    for i, x in enumerate(held):
        buf[i] = x
    state = np.zeros(kern.STATE_SIZE)
    state[kern.N], state[kern.HEAD] = len(held), len(held) % window
    state[kern.SCALE2] = s2 = rng.uniform(0.3, 1.5)
    limit = fusion._trigger_limit
    windows = np.array([4, 8, 16, 32])
    for quantised in (True, False):
        best, want = 1.0, 0
        for w in windows[windows <= len(held)]:
            eff = w / s2 if not quantised else 1 / (max(1 - s2, 0) + s2 / w)
            x = np.append(np.where(ok, held[-w:].mean(axis=0) * math.sqrt(eff) / sigma, 0.0), 0)
            ratio = ((x[fusion._nbr] ** 2).sum(axis=1) / limit).max()
            if ratio > best:
                best, want = ratio, int(w)
        got = kern.idle_scan(buf, state, ok, sigma, fusion._nbr, limit, windows, quantised)
        assert got == want


@given(seed=st.integers(0, 2**31 - 1), m=st.integers(1, 8), dup=st.booleans())
def test_orthonormal_spans_what_numpy_qr_spans(seed, m, dup):
    rng = np.random.default_rng(seed)
    k = 30
    a = rng.normal(size=(k, m))
    if dup and m > 1:
        a[:, -1] = 2.0 * a[:, 0]  # a dependent column is dropped
    ok = rng.random(k) > 0.2
    sigma = rng.uniform(0.5, 2.0, k)
    q = np.zeros((k, m))
    kept = kern.orthonormal(a, ok, sigma, q)
    w = np.where(ok[:, None], a / sigma[:, None], 0.0)
    assert kept == np.linalg.matrix_rank(w)
    qk = q[:, :kept]
    assert np.allclose(qk.T @ qk, np.eye(kept), atol=1e-10)
    ref = np.linalg.qr(w)[0][:, :kept] if not (dup and m > 1) else np.linalg.qr(w[:, :-1])[0]
    # The same subspace: projecting either basis on the other loses nothing.
    assert np.allclose(qk @ (qk.T @ ref), ref, atol=1e-9)
    assert np.all(q[~ok, :kept] == 0.0)


@given(seed=st.integers(0, 2**31 - 1), n=st.integers(3, 20), step=st.floats(0.0, 3.0))
def test_best_split_against_numpy(seed, n, step):
    rng = np.random.default_rng(seed)
    k, m, window = 15, 3, 20
    rows = rng.normal(size=(n, k)) + step * (np.arange(n) >= n // 2)[:, None]
    buf = np.zeros((window, k))
    buf[:n] = rows
    state = np.zeros(kern.STATE_SIZE)
    state[kern.N], state[kern.HEAD] = n, n % window
    total = rows.sum(axis=0)
    sigma = rng.uniform(0.5, 2.0, k)
    q = np.linalg.qr(rng.normal(size=(k, m)))[0]
    y = ((rows - total / n) / sigma) @ q
    stats = [
        j * (n - j) / n * np.sum((y[:j].mean(axis=0) - y[j:].mean(axis=0)) ** 2)
        for j in range(1, n)
    ]
    old, stat = kern.best_split(buf, state, total, sigma, q)
    assert stat == pytest.approx(max(stats), rel=1e-9)
    assert stats[old - 1] == pytest.approx(max(stats), rel=1e-9)
