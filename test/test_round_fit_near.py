"""fit_round_contact's single compiled call (_round_kernels.fit_near) gives, bit for bit, what
its Python steps gave: the taxels within reach of any start (round_contact._near), the start
lattices, fit_one on those taxels, and the prediction and residual at every taxel."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tactile_contact.inverse import _round_kernels as kernels
from tactile_contact.inverse.reconstruction import Reconstructor
from tactile_contact.inverse.round_contact import (
    FIT_CANDIDATES,
    FIT_ITERATIONS,
    FIT_KEEP,
    FIT_PRE_ITERATIONS,
    SEARCH_HALF,
    SEARCH_PITCH,
    SEARCH_RADII,
    THOROUGH_CANDIDATES,
    THOROUGH_HALF,
    THOROUGH_KEEP,
    RoundFit,
    _every,
    _lattice_offsets,
    _near,
    fit_round_contact,
)


def stepwise(tables, xy, d, starts, sigma, thorough=False, polish=True, near=0.015):
    """The search as it was written before fit_near: numpy steps around fit_one."""
    found = _near(tables, xy, d, starts, near, sigma)
    if found is None:
        return None
    local, w2 = found
    t0, dt = tables.log_grid
    offsets = _lattice_offsets(THOROUGH_HALF if thorough else SEARCH_HALF, SEARCH_PITCH)
    _cost, x, y, t, force, fam = kernels.fit_one(
        tables.table,
        t0,
        dt,
        tables.step,
        np.ascontiguousarray(xy[local]),
        np.ascontiguousarray(d[local]),
        np.ascontiguousarray(w2),
        np.ascontiguousarray((starts[:, None, :] + offsets[None]).reshape(-1, 2)),
        np.repeat(np.arange(len(starts)), len(offsets)),
        len(starts),
        _every(len(tables.radii), 1 if thorough else len(tables.radii) // SEARCH_RADII),
        THOROUGH_CANDIDATES if thorough else FIT_CANDIDATES,
        FIT_PRE_ITERATIONS,
        THOROUGH_KEEP if thorough else FIT_KEEP,
        FIT_ITERATIONS if polish else FIT_PRE_ITERATIONS * 2,
    )
    if not force > 0:
        return None
    pred = kernels.predict(tables.table, fam, t0, dt, tables.step, xy, x, y, t, force)
    res = float(np.linalg.norm(pred - d))
    return RoundFit(float(force), (float(x), float(y)), int(fam), float(math.exp(t)), res)


@pytest.fixture(scope="module")
def recon(hexagon_bundle) -> Reconstructor:
    return Reconstructor.from_bundle(hexagon_bundle[0])


def presses(recon: Reconstructor) -> list[tuple[np.ndarray, np.ndarray]]:
    """(readings δ (K,) [m], starts (S, 2) [m]): a press on a taxel, one between taxels and
    two far apart, from the tables' own responses (the fit's input, not its truth: this test
    compares two implementations), 8-bit-like and noisy, with one to four starts."""
    xy = recon.taxel_xy
    rng = np.random.default_rng(5)
    out = []
    for k, (fam, force) in enumerate(((0, 1.0), (1, 2.5), (0, 0.4))):
        c = xy[10 * k + 3].copy() if k != 1 else (xy[20] + xy[21]) / 2
        fit = RoundFit(force, (float(c[0]), float(c[1])), fam, 3e-3, 0.0)
        d = recon._round.predict(fit, xy)
        if k == 2:
            other = RoundFit(1.5, (float(xy[60, 0]), float(xy[60, 1])), 1, 5e-3, 0.0)
            d = d + recon._round.predict(other, xy)
        lsb = float(np.abs(d).max()) / 40
        counts = np.rint(d / lsb + rng.normal(0, 0.3, len(d))) * lsb
        shift = np.array([1.2e-3, -0.7e-3])
        starts = np.array([c, c + shift, xy[int(np.argmax(d))], xy.mean(axis=0)])
        for n in (1, 2, 4):
            out.append((counts, starts[:n]))
        out.append((d + rng.normal(0, 0.01 * float(np.abs(d).max()), len(d)), starts[:2]))
    return out


@pytest.mark.parametrize("weights", ["none", "scalar", "per taxel"])
def test_fit_near_equals_the_stepwise_search(recon, weights):
    xy = recon.taxel_xy
    sigma = {"none": None, "scalar": 2e-6, "per taxel": recon.default_noise}[weights]
    for d, starts in presses(recon):
        for thorough, polish in ((False, True), (False, False), (True, True)):
            want = stepwise(recon._round, xy, d, starts, sigma, thorough, polish)
            got = fit_round_contact(
                recon._round, xy, d, starts, sigma=sigma, thorough=thorough, polish=polish
            )
            assert want is not None
            assert got == want  # every field, bit for bit


def test_no_taxel_within_reach_is_no_fit(recon):
    xy = recon.taxel_xy
    far = xy.max(axis=0) + 0.05
    d = np.ones(len(xy)) * 1e-6
    assert stepwise(recon._round, xy, d, far[None], None) is None
    assert fit_round_contact(recon._round, xy, d, far) is None
    assert fit_round_contact(recon._round, xy, d, np.array([far, far + 0.01])) is None
