"""Reconstruction core: the bundle's matrices are the elastic kernels, contact-free frames are
not solved, the outputs are consistent with each other and with the forward model."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import yaml

from tactile_contact.inverse.reconstruction import ContactResult, Reconstructor
from tactile_contact.model.elastic import love_matrix
from tactile_contact.model.forward import ForwardModel
from tactile_contact.model.grids import disc_quadrature
from tactile_contact.model.indenters import HertzSphere
from tactile_contact.model.layout import load_layout, parse_layout
from tactile_contact.model.sensor import compression_to_delta_c, delta_c_to_compression
from tactile_contact.offline.build import build_patch
from tactile_contact.offline.bundle import BundleStaleError, save_bundle

ROOT = Path(__file__).resolve().parents[1]
DOC = yaml.safe_load((ROOT / "config" / "hexagon_patch.yaml").read_text())


def _bundle(tmp_path_factory, name: str, **sections) -> tuple[Path, object]:
    doc = copy.deepcopy(DOC)
    for sec, kv in sections.items():
        doc["patches"][0].setdefault(sec, {}).update(kv)
    patch = parse_layout(doc).patches[0]
    m, a = build_patch(patch)
    return save_bundle(tmp_path_factory.mktemp(name) / patch.name, m, a), patch


@pytest.fixture(scope="module")
def default(tmp_path_factory):
    path, patch = _bundle(tmp_path_factory, "default")
    return Reconstructor.from_bundle(path, patch), patch


@pytest.fixture(scope="module")
def point_pinv(tmp_path_factory):
    path, patch = _bundle(
        tmp_path_factory,
        "pinv",
        model={"taxel_average": False},
        solver={"method": "pinv", "refine": "none"},
    )
    return Reconstructor.from_bundle(path), patch


def test_public_import():
    import tactile_contact

    assert tactile_contact.Reconstructor is Reconstructor
    assert tactile_contact.ContactResult is ContactResult


def test_forward_matrix_is_the_love_kernel_at_the_taxels(point_pinv):
    r, patch = point_pinv
    g = r.traction_grid
    ref = love_matrix(patch.taxel_xy(), g.centers(), g.half_sizes(), 2e-3, 2.1e5, 0.5)
    np.testing.assert_allclose(r.forward, ref, rtol=1e-12, atol=0)
    assert r.forward.shape == (72, g.n_cells)


def test_forward_matrix_averages_the_kernel_over_the_electrode(default):
    r, patch = default
    g = r.traction_grid
    pts, w = disc_quadrature(2e-3, 12, 32)  # finer than the build's 8 × 24 rule
    k = patch.taxel_xy()[:6]
    ref = love_matrix(
        (k[:, None] + pts[None]).reshape(-1, 2), g.centers(), g.half_sizes(), 2e-3, 2.1e5, 0.5
    ).reshape(6, len(w), -1)
    ref = np.einsum("kqn,q->kn", ref, w)
    scale = np.abs(ref).max()
    np.testing.assert_allclose(r.forward[:6], ref, atol=1e-2 * scale)


def test_boussinesq_bundle_follows_its_model_throughout(tmp_path_factory, default):
    """C, the output deflection operator and the round-contact tables of a ``boussinesq``
    patch all come from the Boussinesq–Cerruti kernel (point force p·A per cell)."""
    from tactile_contact.inverse.round_contact import round_tables
    from tactile_contact.model.elastic import boussinesq_matrix

    path, patch = _bundle(
        tmp_path_factory, "bc", model={"kind": "boussinesq", "taxel_average": False}
    )
    r = Reconstructor.from_bundle(path, patch)
    g, dg = r.traction_grid, r.deflection_grid

    def bc(points):
        return boussinesq_matrix(points, g.centers(), g.cell_area, 2e-3, 2.1e5, 0.5) * g.cell_area

    np.testing.assert_allclose(r.forward, bc(patch.taxel_xy()), rtol=1e-12, atol=0)
    ref = bc(dg.centers())
    np.testing.assert_allclose(
        np.asarray(r.bundle["deflection_operator"]), ref, rtol=1e-6, atol=1e-7 * np.abs(ref).max()
    )
    tables = round_tables(2e-3, 2.1e5, 0.5, 0.0, r.bundle["round_radii"], model="boussinesq")
    np.testing.assert_allclose(r.bundle["round_table"], tables.table, rtol=1e-12, atol=0)
    # Not the Love bundle's (the two models' near fields differ by a few %).
    love = np.asarray(default[0].bundle["deflection_operator"])
    assert np.abs(love - ref).max() > 0.02 * np.abs(ref).max()


def test_params_and_geometry(default):
    r, patch = default
    assert r.params["thickness"] == 2e-3 and r.params["young"] == 2.1e5
    assert r.params["poisson"] == 0.5 and r.params["taxel_radius"] == 2e-3
    with pytest.raises(TypeError):
        r.params["young"] = 1.0  # read-only
    np.testing.assert_array_equal(r.taxel_xy, patch.taxel_xy())
    np.testing.assert_array_equal(r.taxel_ids, patch.taxel_ids())
    assert r.patch == "hexagon" and r.frame_id == "skin_hexagon"


def test_zero_and_subnoise_input_is_not_solved(default):
    r, _ = default
    for d in (np.zeros(72), np.full(72, 0.5 * r.noise) * np.sign(np.arange(72) % 2 - 0.5)):
        res = r.solve_deflection(d)
        assert res.solver == "none" and not res.in_contact and res.solve_time == 0.0
        assert res.total_force == 0.0 and res.cop == (0.0, 0.0) and res.taxels_active == 0
        assert res.traction.shape == r.traction_grid.shape and not res.traction.any()
        assert res.deflection.shape == r.deflection_grid.shape and not res.deflection.any()
    res = r.solve(np.zeros(72), want_deflection=False, want_traction=False)
    assert res.traction is None and res.deflection is None


def test_negative_only_readings_are_contact(default):
    # DESIGN.md: a small punch between three taxels reads about −28 µm at each, nothing positive.
    r, _ = default
    d = np.zeros(72)
    d[[48 + 3, 48 + 7, 48 + 11]] = -28e-6
    res = r.solve_deflection(d)
    # Detected although no taxel reads positive, and fitted as one round contact.
    assert res.in_contact and res.solver == "round" and res.total_force > 0
    centroid = r.taxel_xy[[51, 55, 59]].mean(axis=0)
    assert np.hypot(*(np.asarray(res.cop) - centroid)) < 1.5e-3


@pytest.fixture(scope="module")
def indentation(default):
    r, _ = default
    fm = ForwardModel(r.taxel_xy, 2e-3, 2.1e5, 0.5, taxel_radius=2e-3)
    c = r.taxel_xy[51]
    return fm.compression(HertzSphere(6e-3), 1.5, c), c


def test_noise_free_indentation(default, indentation):
    r, _ = default
    delta, c = indentation
    res = r.solve_deflection(delta)
    assert res.success and res.solver == "round" and res.in_contact
    assert res.total_force == pytest.approx(1.5, rel=0.03)
    assert np.hypot(*(np.asarray(res.cop) - c)) < 0.5e-3
    assert res.traction.min() >= 0 and res.peak_pressure == pytest.approx(res.traction.max())
    assert res.total_force == pytest.approx(res.traction.sum() * r.traction_grid.cell_area)
    # the model explains the data: residual below 10 % of the reading
    assert res.residual_norm < 0.1 * np.linalg.norm(delta)
    # The deflection grid is the fitted contact's effective deflection at the grid's cells:
    # against the fine forward model (point values) of that contact.
    (k,) = res.contacts
    dg = r.deflection_grid
    ref = ForwardModel(dg.centers(), 2e-3, 2.1e5, 0.5, fine_cell=2.5e-4).compression(
        HertzSphere.with_contact_radius(k.radius, k.force, 2.1e5, 0.5), k.force, k.center
    )
    np.testing.assert_allclose(
        dg.to_vector(res.deflection), ref, rtol=0.0, atol=0.02 * np.abs(ref).max()
    )


def test_contacts_add_up_to_the_summary(default, point_pinv, indentation):
    # The default fits one round contact here; its force and centre are the summary's.
    delta, c = indentation
    for r, profiles in ((default[0], ("punch", "hertz")), (point_pinv[0], ("field",))):
        res = r.solve_deflection(delta)
        assert len(res.contacts) == 1
        (k,) = res.contacts
        assert k.profile in profiles
        assert k.force == pytest.approx(res.total_force, rel=1e-12)
        assert k.center == pytest.approx(res.cop, abs=1e-12)
        assert np.pi * k.radius**2 == pytest.approx(res.contact_area, rel=1e-9)
    # The sphere's Hertz contact radius at 1.5 N is 1.9 mm: the fit's disc is near it.
    k = default[0].solve_deflection(delta).contacts[0]
    assert 1.0e-3 < k.radius < 3.5e-3 and np.hypot(*(np.asarray(k.center) - c)) < 0.5e-3
    assert default[0].solve_deflection(np.zeros(72)).contacts == ()


def test_delta_c_and_delta_entry_points_agree(default, indentation):
    r, _ = default
    delta, _ = indentation
    dc = compression_to_delta_c(delta, 2e-3, 4.37, np.pi * 4e-6)
    # With a noise level both read their input as counts (the posterior over the
    # quantisation valley); without, this exact ΔC (a model's, off the count lattice, which
    # its contact explains to far within the 8-bit noise) is read as precise, as its
    # compressions are.
    for noise in (r.default_noise, None):
        a, b = r.solve(dc, noise=noise), r.solve_deflection(delta, noise=noise)
        np.testing.assert_allclose(a.traction, b.traction, rtol=1e-6, atol=1e-6 * b.peak_pressure)
        assert a.total_force == pytest.approx(b.total_force, rel=1e-6)


def test_exact_delta_c_is_read_as_precise_and_8_bit_readings_as_counts(default, indentation):
    """``solve`` without ``noise=``: a model's exact ΔC comes back as the press (read as
    counts, the posterior spread it along the valley), and the same press as 8-bit readings
    with baselines off the lattice (a driver's) still takes the counts' way."""
    r, _ = default
    delta, _ = indentation
    dc = compression_to_delta_c(delta, 2e-3, 4.37, np.pi * 4e-6)
    exact, precise = r.solve(dc), r.solve_deflection(delta)
    assert exact.total_force == pytest.approx(precise.total_force, rel=1e-9)
    from tactile_contact.inverse.readings import Frame

    rng = np.random.default_rng(3)
    lsb = r.readings.lsb
    rest = rng.uniform(0.0, 1.0, 72)
    baseline = np.rint(rest + rng.normal(0.0, 0.3, (20, 72))).mean(axis=0)
    driver = (np.rint(rest + dc / lsb + rng.normal(0.0, 0.3, 72)) - baseline) * lsb
    d, ok = r.readings.from_delta_c(driver, None)
    assert not r.readings.on_count_lattice(d, ok)
    as_counts = r._solve(Frame(d, ok, r.default_noise, estimate=True), True, True)
    got = r.solve(driver)
    assert got.in_contact and got.total_force == as_counts.total_force


def test_invalid_taxels_are_ignored(default, indentation):
    r, _ = default
    delta, _ = indentation
    valid = np.ones(72, bool)
    valid[10] = False
    a = r.solve_deflection(np.where(valid, delta, 1.0), valid=valid)
    b = r.solve_deflection(np.where(valid, delta, 0.0), valid=valid)
    np.testing.assert_array_equal(a.traction, b.traction)
    c = r.solve_deflection(np.where(valid, delta, np.nan))
    np.testing.assert_allclose(c.traction, b.traction, rtol=1e-6, atol=1e-6 * b.peak_pressure)
    # a capacitance at or below −C0 is no compression at all: excluded, not an exception
    dc = compression_to_delta_c(delta, 2e-3, 4.37, np.pi * 4e-6)
    ref = r.solve(np.where(valid, dc, 0.0), valid=valid)
    dc[10] = -1.0
    d = r.solve(dc)
    assert d.total_force == pytest.approx(ref.total_force, rel=1e-6)
    assert d.taxels_used == b.taxels_used == 71
    # Beyond the converter's full scale (no 8-bit reading gives 1 nF, ~4000 C0) and a
    # compression of the whole layer: excluded too, and counted.
    dc[10] = 1e-9
    assert r.solve(dc).total_force == pytest.approx(ref.total_force, rel=1e-6)
    assert r.solve(dc).taxels_used == 71
    e = r.solve_deflection(np.where(valid, delta, 2e-3))
    assert e.total_force == pytest.approx(b.total_force, rel=1e-6) and e.taxels_used == 71
    assert r.solve_deflection(delta).taxels_used == 72


def test_flickering_taxels_keep_the_solver_cache_bounded(tmp_path_factory, indentation):
    """A different taxel out in every frame: the operators kept per set of valid taxels stay
    at SOLVER_CACHE_SIZE, and a set met again after eviction gives the same result."""
    from tactile_contact.inverse.grid_fallback import SOLVER_CACHE_SIZE

    path, patch = _bundle(tmp_path_factory, "flicker")
    r = Reconstructor.from_bundle(path, patch)
    delta, _ = indentation
    rng = np.random.default_rng(5)
    firsts = {}
    for k in range(3 * SOLVER_CACHE_SIZE):
        out = int(rng.integers(72)) if k < 2 * SOLVER_CACHE_SIZE else k - 2 * SOLVER_CACHE_SIZE
        valid = np.ones(72, bool)
        valid[out] = False
        res = r.solve_deflection(delta, valid)
        assert len(r.grid.solvers) <= SOLVER_CACHE_SIZE
        if out in firsts:
            assert res.total_force == pytest.approx(firsts[out], rel=1e-9)
        firsts.setdefault(out, res.total_force)
    assert res.in_contact and res.total_force == pytest.approx(1.5, rel=0.15)


def test_pinv_path_is_the_precomputed_product(point_pinv, indentation):
    r, _ = point_pinv
    delta, _ = indentation
    res = r.solve_deflection(delta)
    assert res.solver == "pinv" and res.iterations == 0
    q = np.linalg.pinv(r.forward, rcond=1e-3) @ delta
    np.testing.assert_allclose(
        r.traction_grid.to_vector(res.traction), q, rtol=1e-4, atol=1e-5 * np.abs(q).max()
    )
    # DESIGN.md §2: the plain pseudo-inverse loses almost all the net force
    assert abs(res.total_force) < 0.5 * 1.5


def test_idle_8bit_deflections_are_no_contact(default):
    # Deflections that are whole counts through the sensor model are read as counts (noise from
    # the rounding, not the scale-free test): a lone count or two on an idle skin is no contact.
    # A lattice test that never matched once let 1109 of 20 000 such frames through.
    r, _ = default
    rng = np.random.default_rng(11)
    counts = np.rint(rng.normal(0.0, 0.15, (3000, 72)))
    counts[counts.any(axis=1) == 0, 5] = 1.0  # every frame carries a count somewhere
    p = r.params
    d = delta_c_to_compression(counts * r.readings.lsb, p["thickness"], p["epsilon_r"], p["area"])
    assert r.readings.on_count_lattice(d[0], np.ones(72, bool))
    assert not r.readings.on_count_lattice(d[0] * 1.05, np.ones(72, bool))
    assert sum(r.solve_deflection(x).in_contact for x in d) == 0


def test_a_noise_array_edited_in_place_is_read_again(default, indentation):
    # The reconstructor remembers the last noise array it checked (the node passes the same
    # tracker array every frame); editing that array in place must still count.
    r, _ = default
    delta, _ = indentation
    weak = 0.2 * delta  # 0.3 N: detected at the sensor model's noise
    sigma = r.default_noise.copy()
    assert r.solve_deflection(weak, noise=sigma).in_contact
    sigma *= 100.0  # the same array, now a hundred times noisier: the press is noise
    assert not r.solve_deflection(weak, noise=sigma).in_contact
    sigma[3] = np.nan
    with pytest.raises(ValueError, match="noise must be finite"):
        r.solve_deflection(weak, noise=sigma)


@pytest.mark.parametrize("level", [1.0, 0.4, 1.28e-15, np.full(72, 2.0)])
def test_a_noise_level_in_counts_or_farads_is_refused_naming_the_unit(default, level) -> None:
    """``noise=`` is compression in metres: a level in counts (1.0: a metre of noise on a
    2 mm layer, which read every press as noise) or in farads (femtometres) is refused."""
    r, _ = default
    with pytest.raises(ValueError, match=r"in metres.*counts or farads"):
        r.solve(np.zeros(72), noise=level)
    assert r.solve(np.zeros(72), noise=1e-9).total_force == 0.0  # (a tiny level is fine)


def test_shape_errors(default):
    r, _ = default
    with pytest.raises(ValueError, match=r"delta_c must have shape \(72,\)"):
        r.solve(np.zeros(71))
    with pytest.raises(ValueError, match=r"valid must have shape \(72,\)"):
        r.solve(np.zeros(72), valid=np.ones(3, bool))


def test_expected_layout_mismatch_is_refused(tmp_path_factory):
    path, _ = _bundle(tmp_path_factory, "stale")
    doc = copy.deepcopy(DOC)
    doc["patches"][0]["solver"]["tikhonov"] = 0.5
    with pytest.raises(BundleStaleError):
        Reconstructor.from_bundle(path, parse_layout(doc).patches[0])
    Reconstructor.from_bundle(path, load_layout(ROOT / "config" / "hexagon_patch.yaml").patches[0])


def test_positively_homogeneous_in_the_data(default, indentation):
    # The least-squares round fit (precise readings) is positively homogeneous: twice the
    # readings give twice the force, the same centre and area (to the fit's tolerance).
    delta, _ = indentation
    r, _ = default
    a, b = r.solve_deflection(delta), r.solve_deflection(2.0 * delta)
    assert a.refined and b.refined
    assert b.total_force == pytest.approx(2.0 * a.total_force, rel=1e-3)
    assert b.cop == pytest.approx(a.cop, abs=2e-6)
    assert b.contact_area == pytest.approx(a.contact_area, rel=1e-2)


def test_a_small_contact_between_the_banks_places_is_reported(default):
    """A 0.2 N, 6 mm sphere between two taxels, read precisely (1 % noise), is a contact: the
    filter bank (five sizes on a 2 mm lattice) explains a third of its energy and misses it,
    the refined test on the fitted contact finds it (bench_robust missed it before)."""
    r, _ = default
    fm = ForwardModel(r.taxel_xy, 2e-3, 2.1e5, 0.5, fine_cell=2.5e-4, taxel_radius=2e-3)
    c = (r.taxel_xy[31] + r.taxel_xy[35]) / 2
    d = fm.compression(HertzSphere(3e-3), 0.2, c)
    d = d + np.random.default_rng(4).normal(size=72) * 0.01 * np.abs(d).max()
    assert not r.detector.detect(d, True)[0]  # the bank alone: no contact
    res = r.solve_deflection(d)
    assert res.in_contact and res.solver == "round"
    assert res.total_force == pytest.approx(0.2, rel=0.15)
    assert np.hypot(*(np.asarray(res.cop) - c)) < 0.5e-3


@pytest.mark.parametrize("passed", [True, False])
def test_noise_alone_stays_no_contact_through_the_refined_test(default, passed):
    """White noise at the assumed level: a few % of frames come near enough to the bank's
    thresholds to be fitted; none passes the refined test (stated rate: 0.1 per hour)."""
    r, _ = default
    rng = np.random.default_rng(8)
    frames = rng.normal(size=(5000, 72)) * r.default_noise
    det = r.detector
    near = sum(det.near_miss(x, det.detect(x, not passed)[1], not passed) for x in frames)
    assert near >= 25  # the refined path ran
    for x in frames:
        res = r.solve_deflection(x, noise=r.default_noise) if passed else r.solve_deflection(x)
        assert not res.in_contact
