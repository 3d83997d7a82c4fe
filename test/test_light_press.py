"""Light presses over a taxel read at 1 count of noise (issue 26, "Noise it did not expect").

Over a taxel only that taxel reads a light press, and a compact weak contact over it and a
3–6× stronger broad one beside it read alike there: the readings cannot rank them, and the
posterior's prior decides (round_contact.posterior_contact). Truth: the fine forward model
(0.25 mm cells, exact Hertz / flat-punch pressure, the bundle's 2 mm electrodes), not the
bundle's radial tables; 8-bit whole counts with 1 count of Gaussian noise before rounding,
through ``solve`` with no noise passed.
"""

from __future__ import annotations

import numpy as np
import pytest

from tactile_contact.inverse import contact_fit
from tactile_contact.inverse.reconstruction import Reconstructor
from tactile_contact.model.forward import ForwardModel
from tactile_contact.model.indenters import FlatPunch, HertzSphere
from tactile_contact.model.sensor import compression_to_delta_c, value_count_farad

#: Module 2's taxel 3: the robust bench's "over a taxel" place there (benchkit.protocol).
TAXEL = 12 * 2 + 3
SEEDS = range(12)


@pytest.fixture(scope="module")
def skin(hexagon_bundle):
    """(reconstructor, patch, truth, 1 count of ΔC [F]) of the default patch."""
    folder, patch = hexagon_bundle
    recon = Reconstructor.from_bundle(folder)
    p = recon.params
    truth = ForwardModel(
        recon.taxel_xy,
        p["thickness"],
        p["young"],
        p["poisson"],
        fine_cell=2.5e-4,
        taxel_radius=p["taxel_radius"],
    )
    lsb = float(value_count_farad(patch.sensor.farad_per_count, patch.sensor.shift))
    return recon, patch, truth, lsb


@pytest.mark.parametrize(
    "indenter",
    [HertzSphere(3e-3), HertzSphere(6e-3), FlatPunch(1.5e-3)],
    ids=["sphere 6 mm", "sphere 12 mm", "punch 3 mm"],
)
def test_a_light_press_over_a_taxel_is_not_reported_as_a_strong_one(skin, indenter):
    """A 0.5 N press over a taxel (≈ 15 counts on it, its neighbours at the noise) in 12
    seeded frames: reported in every frame, at most 2× its force in the median frame (the
    prior uniform in contact radius and the lattice cut at 1.5 mm from the least-squares
    point: 2.5× in the median, 3.5× the worst), and never below half of it."""
    recon, patch, truth, lsb = skin
    force = 0.5
    d = truth.compression(indenter, force, recon.taxel_xy[TAXEL])
    e, s = patch.elastomer, patch.sensor
    dc = compression_to_delta_c(d, e.thickness, s.epsilon_r, s.area)
    assert 12 < dc.max() / lsb < 20  # one taxel reads, a light press
    ratios = []
    for seed in SEEDS:
        rng = np.random.default_rng(seed)
        res = recon.solve(np.rint(dc / lsb + rng.normal(0.0, 1.0, dc.shape)) * lsb)
        assert res.in_contact, seed
        ratios.append(res.total_force / force)
    assert np.median(ratios) <= 2.0, np.round(ratios, 2)
    assert min(ratios) >= 0.5, np.round(ratios, 2)


def _forces(recon, dc, lsb, sigma, seeds):
    """(total force [N], CoP x, y [m]) of ``solve`` on 8-bit readings of ΔC ``dc`` [F] with
    ``sigma`` counts of noise, one row a seed."""
    out = []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        res = recon.solve(np.rint(dc / lsb + rng.normal(0.0, sigma, dc.shape)) * lsb)
        out.append((res.total_force, *res.cop) if res.in_contact else (0.0, 0.0, 0.0))
    return np.array(out)


def test_readings_within_their_rounding_keep_the_prior_weighted_by_radius(skin, monkeypatch):
    """The blend towards a prior uniform in log a acts only on readings noisier than their
    rounding (contact_fit.log_prior_blend): at 0.15 count (the shipped bag, the iCub benches)
    every frame is bit for bit what the prior ∝ a gives (the blend switched off), while at
    1 count the same presses change (the switch is not idle)."""
    recon, patch, truth, lsb = skin
    e, s = patch.elastomer, patch.sensor
    between = 0.5 * (recon.taxel_xy[TAXEL] + recon.taxel_xy[TAXEL + 1])
    presses = [
        (HertzSphere(3e-3), 0.5, recon.taxel_xy[TAXEL]),
        (HertzSphere(6e-3), 1.5, between),
        (FlatPunch(1.5e-3), 2.5, recon.taxel_xy[TAXEL] + 0.7e-3),
    ]
    dcs = [
        compression_to_delta_c(truth.compression(ind, f, c), e.thickness, s.epsilon_r, s.area)
        for ind, f, c in presses
    ]
    gated = {
        sigma: [_forces(recon, dc, lsb, sigma, range(6)) for dc in dcs] for sigma in (0.15, 1.0)
    }
    monkeypatch.setattr(contact_fit, "LOG_PRIOR_FROM", np.inf)
    for sigma, rows in gated.items():
        plain = [_forces(recon, dc, lsb, sigma, range(6)) for dc in dcs]
        same = all(np.array_equal(a, b) for a, b in zip(rows, plain, strict=True))
        assert same == (sigma < 0.5), sigma


def test_the_blend_follows_the_noise_in_units_of_the_rounding():
    """t is 0 up to LOG_PRIOR_FROM × (one count/√6), 1 from LOG_PRIOR_FROM + LOG_PRIOR_SPAN,
    linear between: 0 for the noise of 8-bit readings at 0.15 count as the stage knows it (the
    model's one count/√6: the far taxels read 0.03 count) and for the driver's readings
    (bench_icub: 1.29-1.57 × one count/√6), 1 at 1 count (1.04 count of rounded noise)."""
    q = 1e-5 / np.sqrt(6.0)
    blend = contact_fit.log_prior_blend
    assert blend(q, q) == 0.0 and blend(1.57 * q, q) == 0.0
    assert blend(1.04e-5, q) == 1.0
    mid = (contact_fit.LOG_PRIOR_FROM + 0.5 * contact_fit.LOG_PRIOR_SPAN) * q
    assert blend(mid, q) == pytest.approx(0.5)
