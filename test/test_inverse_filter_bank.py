"""The detector of a patch (tactile_contact.inverse.filter_bank): where its bank looks, what
each filter is, and the false-alarm bound it states."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tactile_contact.inverse.filter_bank import (
    DETECTION_PITCH,
    DETECTION_PROFILES,
    DETECTION_REACH,
    REFINE_PITCH,
    patch_detector,
)
from tactile_contact.inverse.reconstruction import Reconstructor
from tactile_contact.model.grids import distance_to_points


@pytest.fixture(scope="module")
def recon(hexagon_bundle) -> Reconstructor:
    return Reconstructor.from_bundle(hexagon_bundle[0])


def test_bank_covers_the_skin_and_nothing_far_from_it(recon):
    det = patch_detector(recon._round, recon.taxel_xy, 2e-3, recon.default_noise)
    centres = det.centres
    assert distance_to_points(centres, recon.taxel_xy).max() <= DETECTION_REACH + 1e-12
    # Every taxel has a bank place within half a lattice diagonal.
    assert distance_to_points(recon.taxel_xy, centres).max() <= DETECTION_PITCH / math.sqrt(2)
    places = np.unique(centres.round(9), axis=0)
    assert len(centres) == len(DETECTION_PROFILES) * len(places)


def test_each_filter_is_a_tabulated_round_contact(recon):
    det = patch_detector(recon._round, recon.taxel_xy, 2e-3, recon.default_noise)
    n = len(det.centres) // len(DETECTION_PROFILES)
    k = 3 * n + 17  # a place of the fourth profile
    fam, radius = DETECTION_PROFILES[3]
    dist = np.hypot(*(recon.taxel_xy - det.centres[k]).T)
    response = recon._round.response(fam, math.log(radius), dist)
    # The filter is the noise-weighted response normalised: z = 1 for δ = response/‖r/σ‖.
    sigma = recon.default_noise
    delta = response / np.sqrt(np.sum((response / sigma) ** 2))
    assert float(det._filters[k] @ delta.astype(np.float32)) == pytest.approx(1.0, rel=1e-5)


def test_stated_false_alarm_rate(recon):
    det = recon.detector
    assert det.rate_per_hour() == pytest.approx(det.per_hour / 2.0, rel=1e-6)
    # The refined test counts every tabulated profile on the fine lattice: stricter.
    per_centre = round(DETECTION_PITCH / REFINE_PITCH) ** 2
    assert per_centre == 64 and det.refined_threshold > det.threshold
