"""Wrong valleys against a converged truth (issue 26): noise-free presses read through the Love
layer's continuum (tactile_contact.model.elastic.axisymmetric, the limit the cell model converges
to) come back within 5 % and 0.5 mm on the point-taxel bundle.

Five presses of bench/bench_valleys.py (`--truth continuum`), off at 888c2ad (the first four)
or with the continuum tables and the rescan from 3 mm (830b81c: the fifth, −6.2 %):
- 12 mm punches at 2.28 and 1.95 N, +10.9 / +10.7 %: the tables' 0.1 mm cells blurred the
  punch's edge, where a point taxel's reading falls by 8 % of the peak within 0.05 mm (point
  taxels' tables now from the continuum, in 0.05 mm steps: round_contact.table_step);
- 6 mm spheres at 1.06, 1.50 and 1.91 N, −8.4 / −7.2 / −6.2 %: flat radius–force valleys the
  search left at 2.8–3.6 mm spheres; the rescan of broad fits (contact_fit.RESCAN_BROAD, 2 mm,
  either family) finds the true contact, judged over the taxels within RESCAN_NEAR.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tactile_contact.inverse.reconstruction import Reconstructor
from tactile_contact.model.elastic.axisymmetric import round_response
from tactile_contact.model.indenters import FlatPunch, HertzSphere

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def recon(point_taxel_bundle) -> Reconstructor:
    return Reconstructor.from_bundle(point_taxel_bundle)


@pytest.mark.parametrize(
    ("indenter", "force", "centre"),
    [
        (FlatPunch(6e-3), 2.2789438730392666, (-4.8283344379025615e-3, -10.840791250008041e-3)),
        (FlatPunch(6e-3), 1.9549046281469482, (17.111424326163534e-3, -31.80775938131407e-3)),
        (HertzSphere(3e-3), 1.0647475043532952, (21.810102208896787e-3, -14.760722445058053e-3)),
        (HertzSphere(3e-3), 1.5004394673359203, (15.49996100182091e-3, -15.422473370641166e-3)),
        (HertzSphere(3e-3), 1.9057323667103006, (4.6325233749922624e-3, 6.233552477271739e-3)),
    ],
)
def test_noise_free_press_through_the_continuum(recon, indenter, force, centre) -> None:
    p = recon.params
    profile = "punch" if isinstance(indenter, FlatPunch) else "hertz"
    a = indenter.contact_radius(force, p["young"], p["poisson"])
    r = np.hypot(*(recon.taxel_xy - np.asarray(centre)).T)
    delta = force * round_response(profile, a, r, p["thickness"], p["young"], p["poisson"])
    res = recon.solve_deflection(delta)
    assert res.in_contact
    assert abs(res.total_force / force - 1.0) <= 0.05, res.total_force / force - 1.0
    assert math.hypot(*(np.asarray(res.cop) - centre)) <= 0.5e-3
