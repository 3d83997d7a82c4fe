"""Stage 5 (tactile_contact.inverse.result): summaries of round contacts and of fields, the
rendering's force, what is made only when asked for."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from tactile_contact.inverse.readings import Frame
from tactile_contact.inverse.reconstruction import Reconstructor
from tactile_contact.inverse.result import Request
from tactile_contact.inverse.round_contact import RoundFit
from tactile_contact.inverse.summary import summarize


@pytest.fixture(scope="module")
def recon(hexagon_bundle) -> Reconstructor:
    return Reconstructor.from_bundle(hexagon_bundle[0])


def request(want_t=True, want_d=True) -> Request:
    return Request(want_t, want_d, 3, 72, time.perf_counter())


def test_two_contacts_add_up(recon):
    xy = recon.taxel_xy
    fits = [RoundFit(1.0, tuple(xy[30]), 1, 3e-3, 0.0), RoundFit(3.0, tuple(xy[5]), 0, 2e-3, 0.0)]
    res = recon.results.of_contacts(fits, 1e-6, "round", True, 0, request())
    assert res.total_force == pytest.approx(4.0)
    np.testing.assert_allclose(res.cop, (1.0 * xy[30] + 3.0 * xy[5]) / 4.0)
    assert res.contact_area == pytest.approx(math.pi * (3e-3**2 + 2e-3**2))
    assert res.in_contact and res.refined and res.solver == "round"
    assert [c.profile for c in res.contacts] == ["hertz", "punch"]
    # The rendering carries each contact's force on the cells (both well inside the mask).
    cell_area = recon.traction_grid.cell_area
    assert recon.traction_grid.to_vector(res.traction).sum() * cell_area == pytest.approx(4.0)
    assert res.peak_pressure == pytest.approx(res.traction.max())
    assert res.deflection.shape == recon.deflection_grid.shape and res.deflection.max() > 0


def test_grids_only_when_asked_for(recon):
    fits = [RoundFit(1.0, tuple(recon.taxel_xy[30]), 1, 3e-3, 0.0)]
    res = recon.results.of_contacts(fits, 0.0, "round", True, 0, request(False, False))
    assert res.traction is None and res.deflection is None and res.total_force == 1.0
    zero = recon.results.zero(request(True, False))
    assert zero.traction.shape == recon.traction_grid.shape and not zero.traction.any()
    assert zero.deflection is None and not zero.in_contact and zero.taxels_used == 72


def test_a_field_is_summarised_as_summary_does(recon):
    q = np.zeros(recon.forward.shape[1])
    q[[40, 41, 60]] = [3e4, 1e4, 5e3]
    d = recon.forward @ q
    frame = Frame(d + 1e-7, np.ones(recon.n_taxels, bool), recon.default_noise)
    res = recon.results.of_field(q, frame, "nnls", True, 7, request())
    p = recon.params
    s = summarize(
        q,
        recon.traction_grid.centers(),
        recon.traction_grid.cell_area,
        p["rel_threshold"],
        p["min_pressure"],
    )
    assert (res.total_force, res.cop, res.contact_area) == (s.total_force, s.cop, s.contact_area)
    assert res.residual_norm == pytest.approx(1e-7 * math.sqrt(recon.n_taxels), rel=1e-6)
    assert res.solver == "nnls" and res.iterations == 7 and not res.refined
    assert len(res.contacts) == 1 and res.contacts[0].profile == "field"


def test_residual_of_contacts_over_the_taxels_used(recon):
    fit = RoundFit(1.0, tuple(recon.taxel_xy[30]), 1, 3e-3, 0.0)
    d = recon._round.predict(fit, recon.taxel_xy)
    ok = np.ones(recon.n_taxels, bool)
    ok[30] = False
    bad = np.where(ok, d, 0.0)
    bad[31] += 2e-6
    frame = Frame(bad, ok, recon.default_noise)
    assert recon.results.residual_of([fit], frame) == pytest.approx(2e-6)
