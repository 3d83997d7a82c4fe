"""Wrong valleys of broad contacts (issue 26): the hop around a broad fit reaches a punch's needle
valley, and a broad punch fit is rescanned for a sphere through its centre.

With point taxels a 12 mm punch's least-squares valley is a needle (≈ 0.3 mm and 2 % in radius
wide). Two noise-free presses of bench/bench_valleys.py (seed 7) that the search left in a
false valley at 8eb856b (the hop without its punch lattice, round_contact.NEEDLE_*): a 12 mm
punch at 2.51 N reported at −45 %, 1.2 mm off, and one at 2.36 N at −10 %, 2.6 mm off. Truth: the
independent fine forward model (tactile_contact.model.forward.ForwardModel, exact flat-punch
pressure on 0.25 mm cells), read at the taxel centres; the bundle: the default patch with
``footprint_radius: 0`` (as test/test_valleys.py). And a 6 mm sphere at 1.55 N (seed 11) that
the search fitted as a 3.25 mm punch at −11.4 % at 8eb856b: the rescan from a broad punch's
centre (contact_fit.RESCAN_BROAD) finds the sphere.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tactile_contact.inverse.reconstruction import Reconstructor
from tactile_contact.model.forward import ForwardModel
from tactile_contact.model.indenters import FlatPunch, HertzSphere

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def recon(point_taxel_bundle) -> Reconstructor:
    return Reconstructor.from_bundle(point_taxel_bundle)


@pytest.mark.parametrize(
    ("force", "centre"),
    [
        (2.5054642727340113, (7.55005446e-3, -11.80949108e-3)),  # 8eb856b: −45 %, 1.18 mm
        (2.3572381943681253, (20.1848976e-3, 2.31287464e-3)),  # 8eb856b: −10 %, 2.56 mm
    ],
)
def test_broad_punch_needle_valley(recon, force, centre):
    _check(recon, FlatPunch(6e-3), force, centre)


def test_broad_punch_fit_rescanned_for_a_sphere(recon):
    _check(recon, HertzSphere(3e-3), 1.545606075391694, (15.019970288518652e-3, -3.63676582e-3))


def _check(recon, indenter, force, centre):
    p = recon.params
    truth = ForwardModel(recon.taxel_xy, p["thickness"], p["young"], p["poisson"], fine_cell=2.5e-4)
    c = np.array(centre)
    res = recon.solve_deflection(truth.compression(indenter, force, c))
    assert res.in_contact and res.solver == "round"
    assert abs(res.total_force / force - 1.0) <= 0.05, res.total_force
    assert math.hypot(*(np.asarray(res.cop) - c)) <= 0.5e-3, res.cop
