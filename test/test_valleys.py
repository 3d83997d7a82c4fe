"""No wrong valleys (issue 26): noise-free presses through a bundle whose response matches the
truth's are reconstructed to within 5 % of their force and 0.5 mm of their centre.

Truth: the independent fine forward model (tactile_contact.model.forward.ForwardModel, exact
cell-averaged Hertz and flat-punch pressure on 0.25 mm cells, Love kernel), read as point values
at the taxel centres — the sharpest response, whose search landscape has the narrowest valleys.
The bundle: the default patch with ``footprint_radius: 0`` (the response calibration finds for
that truth). Presses: random indenter of the paper's four, 1–3 N, anywhere at least 1.5 mm inside
the hull of the taxel centres (the skin's edge lies 1.5–2 mm beyond its outer taxels), through
``solve_deflection`` as a new user would; and the issue's single case, a 12 mm sphere at 1 N
between the two central taxels of the hexagon, and a press in the middle of the hexagon, 6.8 mm
from every taxel, where the traction grid has no cells.
"""

from __future__ import annotations

import numpy as np
import pytest

from tactile_contact.inverse.reconstruction import Reconstructor
from tactile_contact.model.forward import ForwardModel
from tactile_contact.model.indenters import FlatPunch, HertzSphere

INDENTERS = (HertzSphere(6e-3), HertzSphere(3e-3), FlatPunch(6e-3), FlatPunch(1.5e-3))
#: Presses drawn (the issue's check draws ≥ 200; bench/bench_valleys.py runs those).
N_PRESSES = 40

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def recon(point_taxel_bundle) -> Reconstructor:
    return Reconstructor.from_bundle(point_taxel_bundle)


@pytest.fixture(scope="module")
def truth(recon) -> ForwardModel:
    p = recon.params
    return ForwardModel(recon.taxel_xy, p["thickness"], p["young"], p["poisson"], fine_cell=2.5e-4)


def _inside(xy: np.ndarray, points: np.ndarray, margin: float) -> np.ndarray:
    """Points at least ``margin`` [m] inside the convex hull of ``xy``."""
    from scipy.spatial import ConvexHull

    eq = ConvexHull(xy).equations
    return (eq[:, :2] @ points.T + eq[:, 2:3]).max(axis=0) <= -margin


def _check(recon, truth, indenter, force, centre) -> tuple[float, float]:
    res = recon.solve_deflection(truth.compression(indenter, force, centre))
    assert res.in_contact, (indenter, force, centre)
    err = res.total_force / force - 1.0
    off = float(np.hypot(*(np.asarray(res.cop) - centre)))
    return err, off


def test_random_presses_find_their_own_valley(recon, truth):
    rng = np.random.default_rng(2026)
    lo, hi = recon.taxel_xy.min(axis=0), recon.taxel_xy.max(axis=0)
    bad = []
    done = 0
    while done < N_PRESSES:
        c = rng.uniform(lo, hi)
        if not _inside(recon.taxel_xy, c[None], 1.5e-3)[0]:
            continue
        ind = INDENTERS[rng.integers(len(INDENTERS))]
        force = float(rng.uniform(1.0, 3.0))
        err, off = _check(recon, truth, ind, force, c)
        if abs(err) > 0.05 or off > 0.5e-3:
            bad.append((type(ind).__name__, ind.radius, round(force, 2), c, err, off))
        done += 1
    assert not bad, bad


def test_the_issues_sphere_between_the_central_taxels(recon, truth):
    xy = recon.taxel_xy
    middle = xy.mean(axis=0)
    # The two taxels nearest the hexagon's middle that are neighbours (5.5 mm apart).
    order = np.argsort(np.hypot(*(xy - middle).T))
    a = xy[order[0]]
    b = min((xy[i] for i in order[1:]), key=lambda p: abs(np.hypot(*(p - a)) - 5.5e-3))
    err, off = _check(recon, truth, HertzSphere(6e-3), 1.0, (a + b) / 2)
    assert abs(err) < 0.05 and off < 0.5e-3


@pytest.mark.parametrize("indenter", INDENTERS[:2])
def test_a_press_where_the_grid_has_no_cells_is_reported(recon, truth, indenter):
    """The hexagon's middle lies 6.8 mm from every taxel and beyond the traction grid's mask:
    the fit's contact is reported (it was fitted to 4 % and returned as no contact)."""
    middle = recon.taxel_xy.mean(axis=0)
    err, off = _check(recon, truth, indenter, 1.5, middle)
    assert abs(err) < 0.05 and off < 0.5e-3


@pytest.mark.parametrize("indenter", [HertzSphere(3e-3), FlatPunch(1.5e-3)])
def test_float_readings_noisier_than_the_sensor_model_keep_their_round_contact(
    recon, truth, indenter
):
    """Float readings with 1 % of a 3 N press's peak as noise (6.6–10 µm, above the sensor
    model's 4.3 µm), no noise level passed: the fit measures that noise from the far taxels, so
    its χ² test passes and noise makes no second contact. Before (0817359) most of these frames
    failed the test and took the grid path (one: +43 %, 7 mm off; its fit was −7 %), and one
    fitted a second contact of noise 19 mm away."""
    xy = recon.taxel_xy
    for centre in (xy[12 * 4 + 3], xy[12 * 2 + 3]):  # over a taxel (the robust bench's places)
        clean = truth.compression(indenter, 3.0, centre)
        for seed in range(5):
            rng = np.random.default_rng(seed)
            d = clean + rng.normal(size=clean.shape) * 0.01 * np.abs(clean).max()
            res = recon.solve_deflection(d)
            assert res.solver == "round" and len(res.contacts) == 1, (seed, res.solver)
            # (Not the force: over a taxel the noise alone puts it 10-50 % off now and then,
            # docs/reconstruction.md "The tail over a taxel".)
            assert np.hypot(*(np.asarray(res.cop) - centre)) < 3e-3
