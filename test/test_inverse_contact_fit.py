"""Stage 3 (tactile_contact.inverse.contact_fit): round contacts fitted to the readings, the χ²
gate, the posterior for counts, following. Presses come from the independent fine forward model
(tactile_contact.model.forward), not from the fit's own tables."""

from __future__ import annotations

import numpy as np
import pytest

from tactile_contact.inverse.contact_fit import FOLLOW_FRAMES, ContactFit, Followed
from tactile_contact.inverse.readings import Frame
from tactile_contact.inverse.reconstruction import Reconstructor
from tactile_contact.model.forward import ForwardModel
from tactile_contact.model.indenters import HertzSphere


@pytest.fixture(scope="module")
def setup(hexagon_bundle):
    r = Reconstructor.from_bundle(hexagon_bundle[0])
    p = r.params
    truth = ForwardModel(
        r.taxel_xy,
        p["thickness"],
        p["young"],
        p["poisson"],
        fine_cell=5e-4,
        taxel_radius=p["taxel_radius"],
    )
    fit = ContactFit(r._round, r.taxel_xy, r.readings.count_sigma, r.contact_threshold, 3)
    return r, truth, fit


def press(setup, force: float, where) -> np.ndarray:
    r, truth, _ = setup
    dc = truth.delta_c(HertzSphere(6e-3), force, np.asarray(where), r.params["epsilon_r"])
    return r.compression(dc)


def frame(r, d, quantised=False) -> Frame:
    sigma = np.full(r.n_taxels, 0.01 * np.abs(d).max())
    return Frame(d, np.ones(r.n_taxels, bool), sigma, quantised, not quantised)


def test_a_press_is_found_where_and_as_strong_as_it_is(setup):
    r, _, fit = setup
    where = r.taxel_xy[30] + np.array([1.0e-3, 0.5e-3])
    found = fit.fit(frame(r, press(setup, 1.5, where)), where + 2e-3, None)
    assert found is not None and len(found.fits) == 1
    (c,) = found.fits
    assert c.force == pytest.approx(1.5, rel=0.05)
    assert np.hypot(*(np.asarray(c.center) - where)) < 0.3e-3
    assert found.followed is not None and found.followed.age == 0
    pred = fit.predicted(found.fits, np.ones(r.n_taxels, bool))
    assert found.residual == pytest.approx(np.linalg.norm(pred - press(setup, 1.5, where)))


def test_readings_no_round_contact_explains_fail_the_chi2_gate(setup):
    r, _, fit = setup
    d = np.where(np.arange(r.n_taxels) % 2 == 0, 3e-5, -1e-5)  # every other taxel pressed
    assert fit.fit(frame(r, d), r.taxel_xy.mean(axis=0), None) is None


def test_following_refits_without_search_and_ages(setup):
    r, _, fit = setup
    where = r.taxel_xy[30]
    first = fit.fit(frame(r, press(setup, 1.0, where)), where, None)
    moved = where + np.array([0.3e-3, 0.0])
    again = fit.fit(frame(r, press(setup, 1.0, moved)), None, first.followed)  # no start
    assert again is not None and again.followed.age == 1
    assert np.hypot(*(np.asarray(again.fits[0].center) - moved)) < 0.3e-3
    # Following only (no start) gives up on readings the followed contact cannot explain.
    far = r.taxel_xy[5]
    assert fit.fit(frame(r, press(setup, 1.0, far)), None, first.followed) is None
    old = Followed(first.followed.fit, first.followed.misfit, FOLLOW_FRAMES)
    assert not old.current and first.followed.current


def test_counts_report_the_posterior_mean(setup):
    r, _, fit = setup
    d = press(setup, 2.0, r.taxel_xy[30])
    counts = np.rint(r.readings.counts(d))
    q = r.readings.from_counts(counts)
    quantised = Frame(q, np.ones(r.n_taxels, bool), r.default_noise, True, False)
    precise = Frame(q, np.ones(r.n_taxels, bool), r.default_noise, False, False)
    post = fit.fit(quantised, r.taxel_xy[30], None)
    lsq = fit.fit(precise, r.taxel_xy[30], None)
    assert post is not None and lsq is not None
    assert post.fits[0] != lsq.fits[0]  # the posterior mean is not the least-squares point
    assert post.fits[0].force == pytest.approx(2.0, rel=0.25)
    # What is followed is the least-squares contact either way.
    assert post.followed.fit == lsq.followed.fit


def test_taxels_not_used_are_left_out(setup):
    r, _, fit = setup
    where = r.taxel_xy[30]
    d = press(setup, 1.5, where)
    ok = np.ones(r.n_taxels, bool)
    ok[30] = False
    bad = d.copy()
    bad[30] = 0.0  # an excluded taxel reads 0 in a Frame
    sigma = np.full(r.n_taxels, 0.01 * np.abs(d).max())
    found = fit.fit(Frame(bad, ok, sigma, False, True), where, None)
    assert found is not None and found.fits[0].force == pytest.approx(1.5, rel=0.1)
    assert fit.predicted(found.fits, ok)[30] == 0.0
