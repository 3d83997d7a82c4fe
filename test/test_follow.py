"""Following a contact from frame to frame (``Reconstructor.follow``, the node's default).

Truth from the independent fine forward model (0.25 mm cells, electrode mean), read as 8-bit
counts with converter noise, as the driver delivers them. Following must give what solving
every frame on its own gives, and fall back to the full search when the scene changes.
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import yaml

import tactile_contact.inverse.contacts as contacts
from tactile_contact.inverse.reconstruction import Reconstructor
from tactile_contact.model.forward import ForwardModel
from tactile_contact.model.indenters import FlatPunch, HertzSphere
from tactile_contact.model.layout import parse_layout
from tactile_contact.offline.build import build_patch
from tactile_contact.offline.bundle import save_bundle

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def bundle(tmp_path_factory) -> Path:
    doc = copy.deepcopy(yaml.safe_load((ROOT / "config" / "hexagon_patch.yaml").read_text()))
    patch = parse_layout(doc).patches[0]
    m, a = build_patch(patch)
    return save_bundle(tmp_path_factory.mktemp("follow") / patch.name, m, a)


@pytest.fixture(scope="module")
def truth(bundle):
    r = Reconstructor.from_bundle(bundle)
    return ForwardModel(r.taxel_xy, 2e-3, 2.1e5, 0.5, fine_cell=2.5e-4, taxel_radius=2e-3)


def counts(r: Reconstructor, delta: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The compressions [m] of 8-bit readings of ``delta`` [m] (0.15 count converter noise)."""
    n = np.rint(r.readings.counts(delta) + 0.15 * rng.normal(size=delta.shape))
    return r.readings.from_counts(n)


def solve_all(r: Reconstructor, frames: list[np.ndarray]) -> list:
    return [r.solve_deflection(d, noise=r.default_noise) for d in frames]


@pytest.fixture
def fits(monkeypatch) -> list[int]:
    """Counts the multi-start searches (the real function runs)."""
    calls = [0]
    search = contacts.fit_round_contact

    def counted(*args, **kwargs):
        calls[0] += 1
        return search(*args, **kwargs)

    monkeypatch.setattr(contacts, "fit_round_contact", counted)
    return calls


def test_a_sliding_contact_is_followed_as_well_as_solved_alone(bundle, truth, fits):
    """A 6 mm sphere at 1.5 N slides 45 mm across the patch in 0.56 mm steps (three runs of
    noise): following finds it in as many frames, as accurately, as solving each frame alone,
    for a fraction of the searches. Not frame for frame: an 8-bit frame's valley can hold two
    basins millimetres apart, and which one the fit starts in moves the posterior there."""
    alone = Reconstructor.from_bundle(bundle)
    follow = Reconstructor.from_bundle(bundle, follow=True)
    xy = alone.taxel_xy
    path = [xy[23] + (xy[55] - xy[23]) * s for s in np.linspace(0.0, 1.0, 81)]
    err: dict[str, list[float]] = {"alone": [], "follow": []}
    cop: dict[str, list[float]] = {"alone": [], "follow": []}
    searches = {"alone": 0, "follow": 0}
    clean = [truth.compression(HertzSphere(6e-3), 1.5, c) for c in path]
    for seed in (3, 4, 5):
        rng = np.random.default_rng(seed)
        frames = [counts(alone, x, rng) for x in clean]
        for name, r in (("alone", alone), ("follow", follow)):
            fits[0] = 0
            for res, c in zip(solve_all(r, frames), path, strict=True):
                err[name].append(abs(res.total_force - 1.5) / 1.5)
                if res.in_contact:
                    cop[name].append(float(np.hypot(*np.subtract(res.cop, c))))
            searches[name] += fits[0]
    assert searches["follow"] <= searches["alone"] / 4  # it followed
    assert abs(len(cop["follow"]) - len(cop["alone"])) <= 3  # frames in contact
    assert np.median(err["follow"]) <= np.median(err["alone"]) + 0.03
    assert np.percentile(err["follow"], 75) <= np.percentile(err["alone"], 75) + 0.03
    assert np.median(cop["follow"]) <= np.median(cop["alone"]) + 0.2e-3


def test_a_contact_that_jumps_is_searched_afresh(bundle, truth):
    """From one press to another 25 mm away: the followed contact explains nothing there, and
    the frame's result is the full search's."""
    follow = Reconstructor.from_bundle(bundle, follow=True)
    alone = Reconstructor.from_bundle(bundle)
    xy = alone.taxel_xy
    rng = np.random.default_rng(5)
    here = counts(alone, truth.compression(HertzSphere(6e-3), 1.0, xy[10]), rng)
    far = int(np.argmax(np.hypot(*(xy - xy[10]).T) > 25e-3))
    there = counts(alone, truth.compression(FlatPunch(3e-3), 2.0, xy[far]), rng)
    follow.solve_deflection(here, noise=follow.default_noise)
    got = follow.solve_deflection(there, noise=follow.default_noise)
    want = alone.solve_deflection(there, noise=alone.default_noise)
    assert got.total_force == pytest.approx(want.total_force, rel=1e-9)
    np.testing.assert_allclose(got.cop, want.cop, rtol=0, atol=1e-9)
    assert np.hypot(*(np.subtract(got.cop, xy[far]))) < 2e-3  # there, not at the old place


def test_a_second_contact_ends_following(bundle, truth):
    """A second press appears 20 mm from the followed one: both are reported, as when the
    frame is solved alone."""
    follow = Reconstructor.from_bundle(bundle, follow=True)
    alone = Reconstructor.from_bundle(bundle)
    xy = alone.taxel_xy
    rng = np.random.default_rng(6)
    first = truth.compression(HertzSphere(6e-3), 1.5, xy[20])
    other = int(np.argmin(np.abs(np.hypot(*(xy - xy[20]).T) - 20e-3)))
    both = first + truth.compression(HertzSphere(6e-3), 1.5, xy[other])
    for _ in range(3):
        res = follow.solve_deflection(counts(alone, first, rng), noise=alone.default_noise)
        assert len(res.contacts) == 1
    frame = counts(alone, both, rng)
    got = follow.solve_deflection(frame, noise=follow.default_noise)
    want = alone.solve_deflection(frame, noise=alone.default_noise)
    assert len(got.contacts) == len(want.contacts) == 2
    assert got.total_force == pytest.approx(want.total_force, rel=1e-9)


def test_following_is_off_by_default_and_after_no_contact(bundle, truth):
    """A library reconstructor solves each frame alone; a followed contact is dropped with a
    frame without contact (it cannot start the next press)."""
    r = Reconstructor.from_bundle(bundle)
    assert r.follow is False
    f = Reconstructor.from_bundle(bundle, follow=True)
    rng = np.random.default_rng(7)
    press = counts(f, truth.compression(HertzSphere(6e-3), 1.5, f.taxel_xy[30]), rng)
    f.solve_deflection(press, noise=f.default_noise)
    assert f.followed is not None
    f.solve_deflection(np.zeros(f.n_taxels), noise=f.default_noise)
    assert f.followed is None


def test_noise_right_after_a_followed_press_is_no_contact(bundle, truth):
    """The followed contact is tried before the filter bank; on the noise frame after a
    release it must not be reported (its own matched filter faces the refined threshold):
    300 presses, each followed by white noise at the assumed level."""
    f = Reconstructor.from_bundle(bundle, follow=True)
    rng = np.random.default_rng(11)
    press = counts(f, truth.compression(HertzSphere(6e-3), 1.5, f.taxel_xy[30]), rng)
    for _ in range(300):
        assert f.solve_deflection(press, noise=f.default_noise).in_contact
        assert f.followed is not None
        noise = rng.normal(size=f.n_taxels) * f.default_noise
        assert not f.solve_deflection(noise, noise=f.default_noise).in_contact
