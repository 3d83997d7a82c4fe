"""Synthetic indentation test of the default reconstruction (issue 7, docs/reconstruction.md).

Ground truth from the independent fine forward simulation (exact cell-averaged Hertz and
flat-punch pressure on 0.25 mm cells, mean over each 2 mm electrode, exact capacitance of the
deformed plate), then Gaussian noise of 0.15 8-bit counts RMS and 8-bit quantisation (one count
≈ 10 µm of compression). The paper's indenters (12 mm and 6 mm half-spheres, 12 mm and 3 mm
flat cylinders) over a taxel, between two and between three taxels, at 0.2, 1 and 3 N.
bench/bench_accuracy.py runs the full set (5 forces, 6 positions) and the variants.
"""

from __future__ import annotations

import copy
import itertools
from pathlib import Path

import numpy as np
import pytest
import yaml

from tactile_contact.inverse.reconstruction import Reconstructor
from tactile_contact.model.forward import ForwardModel
from tactile_contact.model.indenters import FlatPunch, HertzSphere
from tactile_contact.model.layout import parse_layout
from tactile_contact.model.sensor import value_count_farad
from tactile_contact.offline.build import build_patch
from tactile_contact.offline.bundle import save_bundle

ROOT = Path(__file__).resolve().parents[1]
DOC = yaml.safe_load((ROOT / "config" / "hexagon_patch.yaml").read_text())
INDENTERS = {
    "sphere 12": HertzSphere(6e-3),
    "sphere 6": HertzSphere(3e-3),
    "cylinder 12": FlatPunch(6e-3),
    "cylinder 3": FlatPunch(1.5e-3),
}
FORCES = (0.2, 1.0, 3.0)
NOISE_COUNTS = 0.15

pytestmark = pytest.mark.slow


def _recon(tmp_path_factory, **solver) -> Reconstructor:
    doc = copy.deepcopy(DOC)
    doc["patches"][0]["solver"].update(solver)
    patch = parse_layout(doc).patches[0]
    m, a = build_patch(patch)
    name = "-".join(f"{k}{v}" for k, v in solver.items()) or "default"
    return Reconstructor.from_bundle(save_bundle(tmp_path_factory.mktemp(name) / "p", m, a))


def _truth(recon: Reconstructor, points, fine_cell: float) -> ForwardModel:
    """The independent fine forward simulation at ``points`` with the bundle's parameters."""
    p = recon.params
    return ForwardModel(
        points,
        p["thickness"],
        p["young"],
        p["poisson"],
        fine_cell=fine_cell,
        taxel_radius=p["taxel_radius"],
    )


@pytest.fixture(scope="module")
def cases(tmp_path_factory):
    recon = _recon(tmp_path_factory)
    p = recon.params
    xy = recon.taxel_xy
    m = xy[48:60]
    positions = {"over": m[3], "two": (m[7] + m[11]) / 2, "three": (m[3] + m[7] + m[11]) / 3}
    # Taxels beyond 20 mm of every indenter read < 1 µm (0.1 count) at 3 N: simulate only the
    # near ones (time), the others read exactly no change.
    near = np.hypot(*(xy - m.mean(axis=0)).T) < 0.02 + 0.008
    fm = _truth(recon, xy[near], fine_cell=2.5e-4)
    lsb = value_count_farad(p["farad_per_count"], p["shift"])
    rng = np.random.default_rng(7)
    out = []
    for (iname, ind), (pname, c), f in itertools.product(
        INDENTERS.items(), positions.items(), FORCES
    ):
        dc = np.zeros(len(xy))
        dc[near] = fm.delta_c(ind, f, c, p["epsilon_r"])
        dcq = np.rint((dc + rng.normal(0, NOISE_COUNTS * lsb, dc.shape)) / lsb) * lsb
        out.append((iname, pname, f, c, dcq))
    return recon, out


def _errors(recon, cases):
    rows = []
    for iname, pname, f, c, dcq in cases:
        res = recon.solve(dcq)
        cop = np.hypot(*(np.asarray(res.cop) - c)) * 1e3 if res.in_contact else np.inf
        rows.append((iname, pname, f, abs(res.total_force / f - 1) * 100, cop))
    return rows


@pytest.fixture(scope="module")
def default_rows(cases):
    recon, cs = cases
    return _errors(recon, cs)


def test_quantisation_is_realistic(cases):
    # One count is about 10 µm; the between-three readings are only a few counts.
    recon, cs = cases
    lsb = value_count_farad(recon.params["farad_per_count"], recon.params["shift"])
    delta_one = recon.compression(np.array([lsb]))[0]
    assert 9e-6 < delta_one < 12e-6
    counts = np.rint(cs[0][4] / lsb)
    assert np.allclose(cs[0][4] / lsb, counts)


def test_centre_of_pressure_median_within_1mm(default_rows):
    # Over the contacts the default detects. Its contact threshold (≈ 1 count) misses readings
    # of one count, which an idle skin's baseline offsets also produce: 25 % of the 0.2 N cases
    # are seen, 75 % at 1 N (contacts between three taxels), all at 3 N. Measured: 0.22 mm
    # (the grid solution alone: 0.25 mm).
    cop = np.array([r[4] for r in default_rows])
    seen = np.isfinite(cop)
    assert np.median(cop[seen]) <= 1.0
    at_1n = np.array([np.isfinite(r[4]) for r in default_rows if r[2] >= 1.0])
    assert at_1n.mean() >= 0.8
    assert all(np.isfinite(r[4]) for r in default_rows if r[2] >= 3.0)


@pytest.fixture(scope="module")
def grid_recon(tmp_path_factory):
    """The grid solution alone (``refine: none``: two-pass NNLS, the earlier default)."""
    return _recon(tmp_path_factory, refine="none")


@pytest.fixture(scope="module")
def grid_rows(grid_recon, cases):
    return _errors(grid_recon, cases[1])


def _offset_cases(recon, cs):
    # A driver's baseline is a mean of quantised samples, so every taxel, loaded or not,
    # carries a fixed offset of up to ±½ count on top of the reading's own quantisation.
    lsb = value_count_farad(recon.params["farad_per_count"], recon.params["shift"])
    rng = np.random.default_rng(3)
    return [(i, p, f, c, dcq + rng.uniform(-0.5, 0.5, dcq.shape) * lsb) for i, p, f, c, dcq in cs]


def test_force_at_3N_and_overall_regression_bounds(default_rows):
    # Measured with the default (round-contact posterior mean): 26.2 % overall (a third of
    # the cases are 0.2 N, mostly below the contact threshold: 100 %), 11.4 % at 3 N, 14.5 %
    # at >= 1 N, 5.1 % over a taxel at >= 1 N; bounds guard against regressions.
    err = np.array([r[3] for r in default_rows])
    f3 = np.array([r[3] for r in default_rows if r[2] == 3.0])
    over = [r[3] for r in default_rows if r[1] == "over" and r[2] >= 1.0]
    assert np.median(f3) <= 16.0
    assert np.median(err) <= 32.0
    assert np.median(over) <= 10.0


def test_default_far_better_than_the_grid_solution(default_rows, grid_rows):
    """The round-contact posterior (tactile_contact.inverse.round_contact) against the two-pass NNLS
    field it refines, on the same cases. Measured: 26.2 % against 46.4 % overall, 14.5 %
    against 29.6 % at >= 1 N."""
    ours = np.median([r[3] for r in default_rows])
    theirs = np.median([r[3] for r in grid_rows])
    assert ours <= 0.7 * theirs
    assert np.median([r[3] for r in default_rows if r[2] >= 1.0]) <= 15.0


def test_default_is_robust_to_the_drivers_baseline_offsets(tmp_path_factory, cases, grid_recon):
    """With the driver's fixed baseline offsets the default still beats the grid solution
    (the older axisymmetric refinement on the 2 mm cells, which won on ideally quantised data
    and lost with offsets, was deleted). Measured with the direct round fit and its posterior
    (issue 16): 32.3 % overall (0.2 N: 100 %, 1 N: 14.5 %, 3 N: 12.7 %) against 42.4 %
    (grid); the earlier posterior around the grid solution measured 23.3 %;
    30.8 % before the fit also searched around the centroid of the strong readings (the grid
    solution's centre of pressure can sit on one side of a broad contact's ring of readings).
    The round fit's least-squares point did 27 % then, but rode the fixed offsets of a
    static press through the whole chain (+26-43 %, test_pipeline.py): see
    test_round_contact.py::test_posterior_is_steadier_than_the_least_squares_point_under_fixed_offsets."""
    recon, cs = cases
    offset_cases = _offset_cases(recon, cs)
    rows = _errors(recon, offset_cases)
    ours = np.median([r[3] for r in rows])
    grid = np.median([r[3] for r in _errors(grid_recon, offset_cases)])
    assert ours <= 34.0
    assert np.median([r[3] for r in rows if r[2] >= 1.0]) <= 15.0
    assert ours < 0.8 * grid


@pytest.mark.xfail(
    strict=True,
    reason="the issue's 10 % median force target is not met over 0.2-3 N: "
    "at <= 0.5 N the force lives in 0-1 count readings (docs/reconstruction.md)",
)
def test_force_median_within_10_percent(default_rows):
    assert np.median([r[3] for r in default_rows]) <= 10.0


def test_default_beats_the_papers_pinv_on_force(tmp_path_factory, cases, default_rows):
    _, cs = cases
    pinv = _errors(_recon(tmp_path_factory, method="pinv", refine="none"), cs)
    ours = np.median([r[3] for r in default_rows if r[2] >= 1.0])
    theirs = np.median([r[3] for r in pinv if r[2] >= 1.0])
    assert ours < 0.6 * theirs


@pytest.fixture(scope="module")
def two_contact_cases(cases):
    """Two indenters pressed at once, 12-25 mm apart, each over a taxel or between two (the
    paper's indenters in turn), 0.15 count noise, 8-bit quantisation. Truth: the same fine
    forward simulation, the two contacts' capacitance changes added (small beside the
    nonlinearity of one contact at these distances)."""
    recon, _ = cases
    p = recon.params
    xy = recon.taxel_xy
    fm = _truth(recon, xy, fine_cell=5e-4)
    lsb = value_count_farad(p["farad_per_count"], p["shift"])
    near = np.hypot(*(xy[:, None] - xy[None]).T) < 6e-3
    mids = [(xy[i] + xy[j]) / 2 for i, j in zip(*np.nonzero(np.tril(near, -1)), strict=True)]
    spots = [*xy, *mids]
    rng = np.random.default_rng(11)
    indenters = list(INDENTERS.values())
    loads = ((1.0, 1.0), (2.0, 1.0), (1.5, 0.7))
    out = []
    while len(out) < 24:
        a, b = rng.choice(len(spots), 2, replace=False)
        c1, c2 = spots[a], spots[b]
        if not 12e-3 <= np.hypot(*(c1 - c2)) <= 25e-3:
            continue
        ind = indenters[len(out) % len(indenters)]
        f1, f2 = loads[len(out) % len(loads)]
        dc = fm.delta_c(ind, f1, c1, p["epsilon_r"]) + fm.delta_c(ind, f2, c2, p["epsilon_r"])
        dcq = np.rint((dc + rng.normal(0, NOISE_COUNTS * lsb, dc.shape)) / lsb) * lsb
        out.append((f1 + f2, (f1 * c1 + f2 * c2) / (f1 + f2), dcq))
    return out


def _two_contact_errors(recon, cs):
    force, cop = [], []
    for f, c, dcq in cs:
        res = recon.solve(dcq)
        force.append(abs(res.total_force / f - 1) * 100)
        cop.append(np.hypot(*(np.asarray(res.cop) - c)) * 1e3)
    return np.median(force), np.median(cop)


def test_two_separate_contacts(tmp_path_factory, cases, two_contact_cases, grid_recon):
    """Two objects at once: the default fits one round contact per pressed region. Against
    one round contact for the whole frame (``max_contacts: 1``) and the grid solution, on the
    same frames. The summary's CoP is the force-weighted centre of both."""
    recon, _ = cases
    force, cop = _two_contact_errors(recon, two_contact_cases)
    one = _recon(tmp_path_factory, max_contacts=1)
    force_one, cop_one = _two_contact_errors(one, two_contact_cases)
    force_grid, cop_grid = _two_contact_errors(grid_recon, two_contact_cases)
    # Measured: 13.0 % and 1.11 mm; one round contact 33.9 % and 5.7 mm (it fits one of the
    # two, or one between them); the grid solution 28.4 % and 3.1 mm (its second NNLS pass
    # keeps the support of the stronger contact only).
    assert force <= 16.0 and cop <= 1.5
    assert force < 0.6 * force_one and cop < 0.5 * cop_one
    assert force < 0.6 * force_grid and cop < 0.5 * cop_grid


def test_single_contacts_stay_single(tmp_path_factory, cases, default_rows):
    """Separate contacts are fitted only when the readings call for them: on the single
    contacts of this test the default gives what one round contact gives."""
    _, cs = cases
    one = _errors(_recon(tmp_path_factory, max_contacts=1), cs)
    assert one == default_rows
