"""Round-contact fit (tactile_contact.inverse.round_contact) against independent references."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from tactile_contact.inverse.reconstruction import Reconstructor
from tactile_contact.inverse.round_contact import (
    FAMILIES,
    TAXEL_SPAN,
    RoundFit,
    RoundTables,
    fit_round_contact,
    follow_round_contact,
    posterior_contact,
    round_tables,
)
from tactile_contact.model.forward import ForwardModel
from tactile_contact.model.indenters import FlatPunch, HertzSphere
from tactile_contact.model.layout import parse_layout
from tactile_contact.model.sensor import value_count_farad
from tactile_contact.offline.build import build_patch
from tactile_contact.offline.bundle import save_bundle

ROOT = Path(__file__).resolve().parents[1]
DOC = yaml.safe_load((ROOT / "config" / "hexagon_patch.yaml").read_text())
H, E, NU, ELECTRODE = 2e-3, 2.1e5, 0.5, 2e-3
RADII = tuple(np.geomspace(0.8e-3, 6.4e-3, 4))  # log-spaced, as the fit needs


@pytest.fixture(scope="module")
def tables():
    return round_tables(H, E, NU, ELECTRODE, RADII, reach=0.016)


def _indenter(family: str, radius: float):
    if family == "punch":
        return FlatPunch(radius)
    return HertzSphere.with_contact_radius(radius, 1.0, E, NU)


@pytest.fixture(scope="module")
def point_tables():
    return round_tables(H, E, NU, 0.0, RADII, reach=0.016)


@pytest.mark.parametrize("family", FAMILIES)
@pytest.mark.parametrize(("electrode", "k"), [(0.0, 0), (0.0, 1), (0.0, 3), (ELECTRODE, 3)])
def test_tables_match_the_contact_centred_forward_model(tables, point_tables, family, k, electrode):
    # ForwardModel builds its own contact-centred 0.1 mm grid and dense Love kernels: a
    # separate code path from the FFT operator and bilinear electrode average of the tables.
    # Where a contact edge lies inside the electrode, the 8 × 24-point average both use is
    # itself the limit (2 % for a 1.5 mm punch), so averaged taxels are compared on the
    # smooth 6 mm contact only.
    # Not within 0.4 a of the contact edge, where a punch's deflection has a log-singular
    # slope and both 0.1 mm discretisations differ by 1-2 %.
    r = np.unique(np.r_[RADII[k] * np.array([0.0, 0.5, 1.6, 2.5]), 12e-3])
    fm = ForwardModel(np.column_stack((r, 0 * r)), H, E, NU, fine_cell=1e-4, taxel_radius=electrode)
    ref = fm.compression(_indenter(family, RADII[k]), 1.0, (0.0, 0.0))
    tab = tables if electrode else point_tables
    got = tab.response(FAMILIES.index(family), np.log(RADII[k]), r)
    # 0.8 mm punch: 8 cells per radius resolve its singular edge to 3 %, larger ones to 0.5 %.
    tol = 3.5e-2 if k == 0 and family == "punch" else 5e-3
    np.testing.assert_allclose(got, ref, rtol=0, atol=tol * np.abs(ref).max())


@pytest.mark.parametrize("family", FAMILIES)
def test_boussinesq_tables_are_the_dense_point_force_sum(point_tables, family):
    """With ``model="boussinesq"`` the tables push point forces p·A through the
    Boussinesq–Cerruti kernel (its Muscari self term included): against the dense
    boussinesq_matrix sum over the same 0.1 mm cells at on-grid distances, and 2-6 % below the
    Love tables under the contact, where the two models' near fields differ."""
    from tactile_contact.model.elastic import boussinesq_matrix

    k, cell = 1, 1e-4
    radius = RADII[k]
    bc = round_tables(H, E, NU, 0.0, RADII, reach=0.016, model="boussinesq")
    n = round(radius / cell) + 1
    grid = np.arange(-n, n + 1) * cell
    centers = np.stack(np.meshgrid(grid, grid, indexing="ij"), axis=-1).reshape(-1, 2)
    shape = _indenter(family, radius)
    p = shape.pressure_on_cells(centers, np.full(2, 0.5 * cell), 1.0, (0.0, 0.0), E, NU)
    r = np.array([0.0, 1.0, 3.0, 5.5, 9.0]) * 1e-3
    pts = np.column_stack((r, 0 * r))
    ref = boussinesq_matrix(pts, centers, cell * cell, H, E, NU) @ (p * cell * cell)
    got = bc.table[FAMILIES.index(family), k, np.rint(r / bc.step).astype(int)]
    np.testing.assert_allclose(got, ref, rtol=1e-6, atol=1e-9 * np.abs(ref).max())
    love = point_tables.table[FAMILIES.index(family), k, 0]
    assert 0.94 * love < got[0] < 0.98 * love


@settings(max_examples=8, deadline=None)
@given(
    st.sampled_from([(0, "love"), (1, "love"), (0, "boussinesq")]),
    st.floats(0.3e-3, 5e-3),
    st.lists(st.floats(0.2e-3, 4e-3), min_size=1, max_size=2),
    st.floats(1e-3, 6e-3),
)
def test_responses_are_the_whole_grid_product(kind, radius, feet, reach):
    """radial_responses convolves the contact's cells with the kernel only over the strip of
    cells its samples read: the same numbers as the operator's FFT product over the whole
    grid (its own tests: against the dense matrices), sampled the same way."""
    import math

    import scipy.ndimage

    from tactile_contact.inverse.round_contact import radial_responses
    from tactile_contact.model.elastic import regular_grid_operator
    from tactile_contact.model.grids import disc_quadrature

    fi, model = kind
    cell, step = 1e-4, 2.5e-4
    got = radial_responses(H, E, NU, feet, [(fi, radius)], reach=reach, step=step, model=model)
    dist = np.arange(round(reach / step) + 1) * step
    n = 2 * math.ceil((reach + max(feet) + 2 * cell) / cell) + 1
    c = (np.arange(n) - n // 2) * cell
    centers = np.stack(np.meshgrid(c, c, indexing="ij"), axis=-1).reshape(-1, 2)
    p = _indenter(FAMILIES[fi], radius).pressure_on_cells(
        centers, np.full(2, cell / 2), 1.0, (0.0, 0.0), E, NU
    )
    op = regular_grid_operator(n, n, cell, cell, H, E, NU, model)
    field = op.matvec(p * (cell * cell if model == "boussinesq" else 1.0)).reshape(n, n)
    for m, r in enumerate(feet):
        q, w = disc_quadrature(r, 8, 24)
        px = (dist[:, None] + q[None, :, 0]) / cell + n // 2
        py = np.broadcast_to(q[None, :, 1] / cell + n // 2, px.shape)
        vals = scipy.ndimage.map_coordinates(field, [px.ravel(), py.ravel()], order=1)
        ref = vals.reshape(px.shape) @ w
        np.testing.assert_allclose(got[0, m], ref, rtol=0, atol=1e-12 * np.abs(ref).max())


def test_tables_show_the_bulge_ring_and_decay(tables):
    t = tables.table
    assert np.isfinite(t).all()
    assert np.all(t[..., 0] > 0)  # compression under the contact
    assert np.all(t[..., round(8e-3 / tables.step)] < 0)  # the layer bulges beside it
    # Small at the reach (the far field decays like r⁻³): 0.2-3 % of the peak at 16 mm.
    assert np.all(np.abs(t[..., -1]) < 0.04 * np.abs(t).max(axis=-1))


@pytest.mark.parametrize("family", FAMILIES)
def test_an_untabulated_radius_reads_like_its_own_table(family):
    # Between tabulated radii (5 % apart, as the bundles' 64) the response is read at distances
    # scaled with the radius. Against a table built at that radius itself (a 5.8 mm contact,
    # point taxels): at a punch's edge the blend at equal distances put the edge half way
    # between the neighbours' (0.3 mm apart: 33 % of the peak off), the scaled one is off by
    # the 0.1 mm cells' own discretisation there (12 %, as a table at 2 mm whose neighbours'
    # edges are one cell apart); elsewhere 4× closer than that blend (1.3 % against 5 %); the
    # far field, which does not scale, within 0.01 % of the peak.
    fam = FAMILIES.index(family)
    grid = round_tables(H, E, NU, 0.0, np.geomspace(5.7e-3, 6.3e-3, 3), reach=0.016)
    mid = float(np.sqrt(grid.radii[0] * grid.radii[1]))  # half way in log radius
    own = round_tables(H, E, NU, 0.0, [mid, 1.05 * mid], reach=0.016)
    r = np.arange(0.0, 12e-3, 0.05e-3)
    want = own.response(fam, np.log(mid), r)
    got = grid.response(fam, np.log(mid), r)
    blend = 0.5 * (
        grid.response(fam, np.log(grid.radii[0]), r) + grid.response(fam, np.log(grid.radii[1]), r)
    )
    peak = np.abs(want).max()
    edge = np.abs(r - mid) < 0.3e-3
    err, before = np.abs(got - want) / peak, np.abs(blend - want) / peak
    assert err[edge].max() < 0.15 and err[edge].max() < 0.5 * before[edge].max()
    assert err[~edge].max() < 0.02 and err[~edge].max() < 0.5 * before[~edge].max()
    assert err[r > 2 * mid].max() < 2e-4
    # The derivatives the fit uses are those of the interpolant.
    from tactile_contact.inverse._round_kernels import _response, _row

    t0, dt = grid.log_grid
    k, w = _row(grid.table, t0, dt, np.log(mid))
    for dist in (0.5e-3, mid + 0.07e-3, 4e-3):
        _, d_t, d_r = _response(grid.table, fam, k, w, dt, grid.step, dist)
        h = 1e-7
        num_t = (
            grid.response(fam, np.log(mid) + h, [dist])[0]
            - grid.response(fam, np.log(mid) - h, [dist])[0]
        ) / (2 * h)
        num_r = (
            grid.response(fam, np.log(mid), [dist + 1e-9])[0]
            - grid.response(fam, np.log(mid), [dist - 1e-9])[0]
        ) / 2e-9
        assert d_t == pytest.approx(num_t, rel=1e-5, abs=1e-9 * peak)
        assert d_r == pytest.approx(num_r, rel=1e-5, abs=1e-3 * peak)


@pytest.fixture(scope="module")
def fine_tables():
    """Radii 10 % apart (the bundles': 5 %), enough for the search (the 4 radii of ``tables``,
    a factor 2 apart, leave kinks in the interpolant that stop a short run; the thorough
    search still finds the contact there)."""
    return round_tables(H, E, NU, ELECTRODE, np.geomspace(1.2e-3, 4.3e-3, 14), reach=0.016)


@pytest.mark.parametrize("which", ["fine", "coarse, thorough"])
def test_fit_recovers_a_contact_off_the_search_lattice(tables, fine_tables, which):
    tab, thorough = (fine_tables, False) if which == "fine" else (tables, True)
    xy = np.array([[i * 5.5e-3, j * 5.5e-3] for i in range(-2, 3) for j in range(-2, 3)])
    xy[:, 0] += 0.3e-3 * (np.arange(len(xy)) % 3)  # not a symmetric lattice
    centre, log_a, force = np.array([1.37e-3, -2.11e-3]), np.log(2.2e-3), 1.7
    delta = force * tab.response(1, log_a, np.hypot(*(xy - centre).T))
    fit = fit_round_contact(tab, xy, delta, start_xy=(0.0, 0.0), thorough=thorough)
    assert fit is not None and FAMILIES[fit.family] == "hertz"
    # Exact data, but the tables are interpolated linearly in r and log a: the cost has kinks
    # along the shallow size/centre valley, which bounds recovery to a few 1e-3.
    assert fit.force == pytest.approx(force, rel=5e-3)
    assert np.hypot(*(np.asarray(fit.center) - centre)) < 2e-5
    assert fit.radius == pytest.approx(2.2e-3, rel=1e-2)
    # Positively homogeneous: twice the readings, twice the force, same contact.
    fit2 = fit_round_contact(tab, xy, 2 * delta, start_xy=(0.0, 0.0), thorough=thorough)
    assert fit2.force == pytest.approx(2 * fit.force, rel=1e-6)
    assert fit2.center == pytest.approx(fit.center, abs=1e-9)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31), st.floats(-12, -3))
def test_fit_is_finite_or_none_on_any_readings(tables, seed, scale):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-0.02, 0.02, size=(12, 2))
    fit = fit_round_contact(tables, xy, rng.normal(size=12) * 10.0**scale, start_xy=xy[0])
    if fit is not None:
        values = (fit.force, *fit.center, fit.radius, fit.residual)
        assert np.all(np.isfinite(values)) and fit.force > 0
        assert RADII[0] <= fit.radius <= RADII[-1]


def test_a_followed_contact_converges_to_the_searched_one(fine_tables):
    """From the last frame's contact 0.4 mm and 15 % in radius away, in the other family: the
    local fit lands where the multi-start search does, and at the truth."""
    xy = np.array([[i * 5.5e-3, j * 5.5e-3] for i in range(-2, 3) for j in range(-2, 3)])
    xy[:, 0] += 0.3e-3 * (np.arange(len(xy)) % 3)
    centre, force = np.array([1.37e-3, -2.11e-3]), 1.7
    delta = fine_tables.predict(RoundFit(force, tuple(centre), 1, 2.2e-3, 0.0), xy)
    last = RoundFit(1.2, (1.7e-3, -1.9e-3), 0, 2.55e-3, 0.0)
    got = follow_round_contact(fine_tables, xy, delta, last)
    searched = fit_round_contact(fine_tables, xy, delta, start_xy=(0.0, 0.0))
    assert got is not None and FAMILIES[got.family] == "hertz"
    assert got.force == pytest.approx(searched.force, rel=1e-6)
    assert got.center == pytest.approx(searched.center, abs=1e-8)
    assert got.force == pytest.approx(force, rel=5e-3)
    assert np.hypot(*(np.asarray(got.center) - centre)) < 2e-5
    # Nothing to follow: no taxel within reach of the last contact, or no positive force.
    assert follow_round_contact(fine_tables, xy, delta, _start((0.2, 0.2))) is None
    assert follow_round_contact(fine_tables, xy, -delta, last) is None


def test_profile_rows_are_the_table_distance_major(tables):
    for stride in (1, 2):
        rows, log_radius, family = tables.profile_rows(stride)
        sub = tables.table[:, ::stride]
        n_a = sub.shape[1]
        for f in range(len(FAMILIES)):
            for k in range(n_a):
                np.testing.assert_array_equal(rows[:, f * n_a + k], sub[f, k])
                assert family[f * n_a + k] == f
                assert np.exp(log_radius[f * n_a + k]) == pytest.approx(tables.radii[k * stride])
        assert tables.profile_rows(stride)[0] is rows  # built once
        assert not rows.flags.writeable


def test_shared_tables_are_one_object_per_content(tables):
    mine = tables.table.copy()
    a = RoundTables.shared(tables.radii, tables.step, mine)
    assert mine.flags.writeable  # the caller's array is not frozen
    b = RoundTables.shared(tables.radii.copy(), tables.step, tables.table.copy())
    assert a is b
    np.testing.assert_array_equal(a.table, tables.table)
    assert not a.table.flags.writeable and not a.radii.flags.writeable
    other = tables.table.copy()
    other[0, 0, 0] *= 1.0 + 1e-12  # any difference, however small: other tables
    assert RoundTables.shared(tables.radii, tables.step, other) is not a
    assert RoundTables.shared(tables.radii, tables.step * 2, tables.table) is not a
    xy = SQUARE[:20]
    fit = RoundFit(1.0, (1e-3, -2e-3), 1, 2e-3, 0.0)
    np.testing.assert_array_equal(a.predict(fit, xy), tables.predict(fit, xy))


SQUARE = np.array([[i * 5.5e-3, j * 5.5e-3] for i in range(-3, 4) for j in range(-3, 4)])


def _start(centre, radius=1.5e-3, family=1):
    return RoundFit(1.0, tuple(centre), family, radius, 0.0)


def test_fit_is_mirror_symmetric_homogeneous_and_unit_free_in_its_weights(tables):
    rng = np.random.default_rng(5)
    centre = np.array([0.7e-3, 0.0])
    delta = 2.0 * tables.response(1, np.log(2.2e-3), np.hypot(*(SQUARE - centre).T))
    delta += rng.normal(0, 3e-6, delta.shape)
    fit = fit_round_contact(tables, SQUARE, delta, centre, sigma=5e-6)
    # Mirror the taxels, the data and the start about x = 0: the answer mirrors.
    fit_m = fit_round_contact(tables, SQUARE * [-1, 1], delta, centre * [-1, 1], sigma=5e-6)
    assert fit_m.force == pytest.approx(fit.force, rel=1e-6)
    assert fit_m.center == pytest.approx((-fit.center[0], fit.center[1]), abs=1e-9)
    # k × the readings: k × the force, the same contact; the weights' unit does not matter.
    fit_k = fit_round_contact(tables, SQUARE, 3 * delta, centre, sigma=1.0)
    assert fit_k.force == pytest.approx(3 * fit.force, rel=1e-6)
    assert fit_k.center == pytest.approx(fit.center, abs=1e-9)
    assert fit_k.radius == pytest.approx(fit.radius, rel=1e-6)


def test_weights_follow_the_per_taxel_noise(tables):
    # A taxel given a huge noise level no longer pulls the fit: corrupting it changes nothing.
    centre = np.array([0.4e-3, 0.9e-3])
    delta = 1.5 * tables.response(0, np.log(RADII[2]), np.hypot(*(SQUARE - centre).T))
    sigma = np.full(len(SQUARE), 1e-6)
    clean = fit_round_contact(tables, SQUARE, delta, centre, sigma=sigma)
    bad = delta.copy()
    k = int(np.argmax(delta))
    bad[k] += 50e-6
    sigma[k] = 1.0
    fit = fit_round_contact(tables, SQUARE, bad, centre, sigma=sigma)
    assert fit.force == pytest.approx(clean.force, rel=1e-3)
    assert fit.force == pytest.approx(1.5, rel=1e-2)


def _posterior_reference(tables, xy, d, fit, sigma, half, step, near, t):
    """posterior_contact by its definition, in numpy: np.interp along each tabulated row, the
    force's closed-form optimum, weights exp(−χ²/2)·a^(1−t) over the whole lattice; with t > 0,
    over the bounding box of the lattice and the lattice moved onto the brightest taxel when
    that taxel lies beyond the lattice and within TAXEL_SPAN; else, when the mean centre
    rounds to another lattice point, again over the lattice's bounding box grown to cover it
    moved there."""
    local = np.hypot(*(xy - fit.center).T) <= near
    xy, d = xy[local], d[local]
    n = round(half / step)
    r_j = np.arange(tables.table.shape[2]) * tables.step

    def mean(lo, hi):
        centres = np.array(
            [
                (fit.center[0] + u * step, fit.center[1] + v * step)
                for u in range(lo[0], hi[0] + 1)
                for v in range(lo[1], hi[1] + 1)
            ]
        )
        rows = []
        for f in range(len(FAMILIES)):
            for k, a in enumerate(tables.radii):
                for c in centres:
                    resp = np.interp(np.hypot(*(xy - c).T), r_j, tables.table[f, k], right=0.0)
                    num, den = resp @ d, resp @ resp
                    if num > 0 and den > 0:
                        cost = (d @ d - num * num / den) / sigma**2
                        rows.append((f, a, c, num / den, cost))
        best = min(r[4] for r in rows)
        w = np.array([np.exp(-0.5 * (r[4] - best)) * r[1] ** (1.0 - t) for r in rows])
        w /= w.sum()
        family_mass = [w[[r[0] == f for r in rows]].sum() for f in range(len(FAMILIES))]
        return (
            np.exp(w @ np.log([r[3] for r in rows])),
            w @ np.array([r[2] for r in rows]),
            np.exp(w @ np.log([r[1] for r in rows])),
            int(np.argmax(family_mass)),
        )

    if t > 0.0:
        kt = np.rint((xy[np.argmax(d)] - np.asarray(fit.center)) / step).astype(int)
        if n < np.abs(kt).max() <= round(TAXEL_SPAN / step):
            return mean(tuple(np.minimum(-n, kt - n)), tuple(np.maximum(n, kt + n)))
    first = mean((-n, -n), (n, n))
    k = np.rint((first[1] - np.asarray(fit.center)) / step).astype(int)
    if t == 0.0 or not k.any():
        return first
    return mean(tuple(np.minimum(-n, k - n)), tuple(np.maximum(n, k + n)))


@pytest.mark.parametrize(
    ("where", "force", "off", "t"),
    [
        ((0.0, 0.0), 0.4, (3e-4, -2e-4), 0.0),
        ((1.1e-3, -0.7e-3), 1.5, (3e-4, -2e-4), 0.0),
        ((0.0, 0.0), 0.4, (1.2e-3, 0.7e-3), 0.0),  # the mean 2 steps away, t = 0: not grown
        ((0.0, 0.0), 0.4, (3e-4, -2e-4), 1.0),
        ((1.1e-3, -0.7e-3), 1.5, (3e-4, -2e-4), 0.4),
        ((0.0, 0.0), 0.4, (1.2e-3, 0.7e-3), 1.0),  # the mean 2 lattice steps away: grown
        ((0.0, 0.0), 0.4, (1.2e-3, 0.7e-3), 0.6),
        ((0.0, 0.0), 0.4, (3.6e-3, 1.1e-3), 1.0),  # the brightest taxel beyond: grown to it
        ((0.0, 0.0), 0.4, (3.6e-3, 1.1e-3), 0.0),  # t = 0: not
    ],
)
def test_posterior_is_its_definition(tables, where, force, off, t):
    """The compiled lattice and its reduction against a plain-numpy evaluation of the model in
    the docstring, on noisy readings of an off-lattice Hertz contact, from a fit ``off`` [m]
    beside it, with the radius prior's blend ``t`` (log_prior)."""
    g = np.arange(-3, 4) * 3e-3
    xy = np.array([(x + 0.5e-3 * (y / 3e-3 % 2), y) for x in g for y in g])
    truth = RoundFit(force, where, 1, 2.2e-3, 0.0)
    rng = np.random.default_rng(2)
    sigma = 4e-6
    d = tables.predict(truth, xy) + rng.normal(0.0, sigma, len(xy))
    start = RoundFit(force * 1.1, (where[0] + off[0], where[1] + off[1]), 1, 2.0e-3, 0.0)
    got = posterior_contact(
        tables, xy, d, start, sigma, half=1e-3, step=5e-4, near=0.012, log_prior=t
    )
    f, c, a, fam = _posterior_reference(tables, xy, d, start, sigma, 1e-3, 5e-4, 0.012, t)
    assert got.force == pytest.approx(f, rel=1e-9)
    assert np.allclose(got.center, c, rtol=0, atol=1e-12)
    assert got.radius == pytest.approx(a, rel=1e-9)
    assert got.family == fam
    assert got.residual == start.residual


def test_noisy_posterior_reaches_a_light_press_over_a_lone_taxel(tables):
    """Noisy readings (log_prior 1) where only one taxel reads: from a least-squares point
    that is a broad contact 4.5 mm off (its edge over the taxel, stronger), the posterior's
    lattice reaches the taxel, and the contact comes back over it and near its force; the
    lattice around that point alone (log_prior 0) stays off it."""
    xy = SQUARE
    truth = RoundFit(0.2, (0.0, 0.0), 1, 0.8e-3, 0.0)
    rng = np.random.default_rng(4)
    sigma = 2e-6
    d = tables.predict(truth, xy) + rng.normal(0.0, sigma, len(xy))
    start = RoundFit(2.0, (4.5e-3, 0.5e-3), 0, 4.0e-3, 0.0)
    got = posterior_contact(tables, xy, d, start, sigma, log_prior=1.0)
    # (Grown once towards the mean alone, as before the taxel's lattice: 1.6 mm, 0.40 N.)
    assert np.hypot(*got.center) < 1.0e-3
    assert 0.1 < got.force < 0.35
    stay = posterior_contact(tables, xy, d, start, sigma, log_prior=0.0)
    assert np.hypot(*stay.center) > 1.4e-3 and stay.force > 0.4  # (the lattice's edge)


def test_posterior_prior_blend_is_checked(tables):
    """log_prior outside [0, 1] is refused, naming it."""
    fit = RoundFit(1.0, (0.0, 0.0), 1, 2.0e-3, 0.0)
    with pytest.raises(ValueError, match="log_prior"):
        posterior_contact(tables, SQUARE, np.zeros(len(SQUARE)), fit, 1e-6, log_prior=1.5)


def test_round_refinement_in_the_reconstructor(tmp_path):
    doc = copy.deepcopy(DOC)
    doc["patches"][0]["solver"]["refine"] = "round"
    patch = parse_layout(doc).patches[0]
    manifest, arrays = build_patch(patch)
    assert arrays["round_table"].shape[:2] == (len(FAMILIES), len(arrays["round_radii"]))
    r = Reconstructor.from_bundle(save_bundle(tmp_path / "p", manifest, arrays), patch)
    fm = ForwardModel(r.taxel_xy, H, E, NU, fine_cell=2.5e-4, taxel_radius=ELECTRODE)
    centre = (r.taxel_xy[51] + r.taxel_xy[55]) / 2
    res = r.solve_deflection(fm.compression(HertzSphere(6e-3), 2.0, centre))
    assert res.refined and res.in_contact
    # Between two taxels size, centre and force trade off along a valley; the default reports
    # the posterior mean over it (σ ≈ 4.3 µm), which on these noise-free data sits 0.44 mm
    # from the centre (the least-squares point: 0.2 mm, 1.81 N), at 1.99 N.
    assert res.total_force == pytest.approx(2.0, rel=0.12)
    assert np.hypot(*(np.asarray(res.cop) - centre)) < 0.6e-3
    assert np.all(res.traction >= 0) and res.traction.sum() > 0
    # Two separate contacts: one round contact each.
    two = fm.compression(HertzSphere(6e-3), 1.0, r.taxel_xy[20])
    two += fm.compression(HertzSphere(6e-3), 1.0, r.taxel_xy[51])
    res = r.solve_deflection(two)
    # Measured (40 mm apart, noise-free): 1.92 N, CoP 0.06 mm from their midpoint.
    assert res.refined
    assert res.total_force == pytest.approx(2.0, rel=0.08)
    # One contact each, reported separately.
    assert len(res.contacts) == 2
    for i in (20, 51):
        k = min(res.contacts, key=lambda k: np.hypot(*(np.asarray(k.center) - r.taxel_xy[i])))
        assert np.hypot(*(np.asarray(k.center) - r.taxel_xy[i])) < 0.3e-3
        assert k.force == pytest.approx(1.0, rel=0.1)
    assert np.hypot(*(np.asarray(res.cop) - (r.taxel_xy[20] + r.taxel_xy[51]) / 2)) < 0.3e-3
    # Idle taxels far away reading 1.8 counts (the driver's baseline offsets) seed nothing:
    # the result is the single contact's.
    one = fm.compression(HertzSphere(6e-3), 2.0, centre)
    idle = one.copy()
    lsb = value_count_farad(r.params["farad_per_count"], r.params["shift"])
    far = np.flatnonzero(np.hypot(*(r.taxel_xy - centre).T) > 0.015)[::20]
    idle[far] += 1.8 * r.compression(np.array([lsb]))[0]
    with_idle = r.solve_deflection(idle)
    alone = r.solve_deflection(one)
    assert len(with_idle.contacts) == len(alone.contacts) == 1
    assert with_idle.total_force == pytest.approx(alone.total_force, rel=1e-6)
    assert np.hypot(*(np.asarray(with_idle.cop) - alone.cop)) < 1e-6
    # Limited to one, a round contact cannot explain the two: the grid solution stays.
    r.max_contacts = 1
    assert not r.solve_deflection(two).refined
    assert r.solve_deflection(idle).total_force == with_idle.total_force
