"""Numerical invariants that must never break (issue 6): unit neutrality, float32 online
products, conditioning of square problems, inverse∘forward, superposition, finiteness."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import yaml

from tactile_contact.inverse.reconstruction import Reconstructor
from tactile_contact.inverse.solvers import SvdInverse
from tactile_contact.model.elastic import love_matrix
from tactile_contact.model.forward import ForwardModel
from tactile_contact.model.indenters import HertzSphere
from tactile_contact.model.layout import parse_layout
from tactile_contact.offline.build import build_patch
from tactile_contact.offline.bundle import save_bundle

ROOT = Path(__file__).resolve().parents[1]
DOC = yaml.safe_load((ROOT / "config" / "hexagon_patch.yaml").read_text())


def _recon(tmp_path_factory: pytest.TempPathFactory, **sections: dict) -> Reconstructor:
    doc = copy.deepcopy(DOC)
    for sec, kv in sections.items():
        doc["patches"][0].setdefault(sec, {}).update(kv)
    patch = parse_layout(doc).patches[0]
    m, a = build_patch(patch)
    return Reconstructor.from_bundle(save_bundle(tmp_path_factory.mktemp("inv") / "p", m, a))


@pytest.fixture(scope="module")
def load(tmp_path_factory: pytest.TempPathFactory) -> tuple[Reconstructor, np.ndarray]:
    r = _recon(tmp_path_factory)
    p = r.params
    fm = ForwardModel(r.taxel_xy, p["thickness"], p["young"], p["poisson"], 2.5e-4, 2e-3)
    return r, fm.compression(HertzSphere(6e-3), 2.0, r.taxel_xy[40])


def square_grid(n: int, pitch: float) -> tuple[np.ndarray, np.ndarray]:
    c = (np.arange(n) - (n - 1) / 2) * pitch
    xx, yy = np.meshgrid(c, c)
    return np.column_stack([xx.ravel(), yy.ravel()]), np.full(2, pitch / 2)


def test_pressure_scales_with_young_modulus(
    tmp_path_factory: pytest.TempPathFactory, load: tuple[Reconstructor, np.ndarray]
) -> None:
    # δ = C(E) q with C ∝ 1/E: the same compressions on a twice stiffer skin mean twice the
    # pressure everywhere, the same CoP and the same contact area (λ is relative to s₁).
    r1, delta = load
    young = float(DOC["patches"][0]["elastomer"]["young"])  # YAML 1.1 reads 2.1e5 as text
    r2 = _recon(tmp_path_factory, elastomer={"young": 2 * young})
    a, b = r1.solve_deflection(delta), r2.solve_deflection(delta)
    assert b.total_force == pytest.approx(2 * a.total_force, rel=1e-6)
    assert b.cop == pytest.approx(a.cop, abs=1e-9)
    assert b.contact_area == pytest.approx(a.contact_area, rel=1e-9)
    np.testing.assert_allclose(b.traction, 2 * a.traction, rtol=1e-5, atol=1e-6 * a.peak_pressure)


def test_float32_online_product_is_within_1e_5_of_float64() -> None:
    pts, half = square_grid(12, 2e-3)
    c = love_matrix(pts[::3], pts, half, 2e-3, 2.1e5, 0.5)
    op = SvdInverse(c).tikhonov_operator(0.1 * np.linalg.norm(c, 2))
    d = c @ np.random.default_rng(0).uniform(0, 1e4, len(pts))
    exact = op @ d
    single = (op.astype(np.float32) @ d.astype(np.float32)).astype(np.float64)
    assert np.abs(single - exact).max() <= 1e-5 * np.abs(exact).max()


@pytest.mark.parametrize("pitch_over_h", [0.25, 0.5, 1.0, 2.0])
def test_square_love_problems_are_well_conditioned(pitch_over_h: float) -> None:
    # DESIGN.md §2: κ ≈ max(0.94·h/d, 0.19·L/h) for square problems (same grid for pressures
    # and measurements); a factor 3 either way allows for the formula being a fit.
    h, n = 2e-3, 12
    d = pitch_over_h * h
    pts, half = square_grid(n, d)
    kappa = np.linalg.cond(love_matrix(pts, pts, half, h, 2.1e5, 0.5))
    estimate = max(0.94 * h / d, 0.19 * n * d / h)
    assert estimate / 3 <= kappa <= 3 * estimate, (kappa, estimate)


def test_inverse_of_a_square_problem_undoes_the_forward_map() -> None:
    pts, half = square_grid(10, 2e-3)
    c = love_matrix(pts, pts, half, 2e-3, 2.1e5, 0.5)
    np.testing.assert_allclose(SvdInverse(c).pinv_operator(1e-12) @ c, np.eye(len(pts)), atol=1e-9)


def test_the_linear_path_superposes(tmp_path_factory: pytest.TempPathFactory) -> None:
    r = _recon(tmp_path_factory, solver={"method": "tikhonov", "refine": "none"})
    p = r.params
    fm = ForwardModel(r.taxel_xy, p["thickness"], p["young"], p["poisson"], 2.5e-4, 2e-3)
    a = fm.compression(HertzSphere(6e-3), 1.0, r.taxel_xy[10])
    b = fm.compression(HertzSphere(3e-3), 2.0, r.taxel_xy[50])
    ra, rb, rab = r.solve_deflection(a), r.solve_deflection(b), r.solve_deflection(a + b)
    np.testing.assert_allclose(
        rab.traction, ra.traction + rb.traction, atol=1e-3 * rab.peak_pressure
    )


@pytest.mark.parametrize("scale", [1e-12, 1e-9, 1e-6, 1e-4, 1.5e-3])
def test_no_nan_or_inf_for_extreme_finite_readings(
    load: tuple[Reconstructor, np.ndarray], scale: float
) -> None:
    r, _ = load
    rng = np.random.default_rng(int(-np.log10(scale) * 10))
    res = r.solve_deflection(rng.uniform(-1, 1, r.n_taxels) * scale)
    values = [res.total_force, res.contact_area, res.peak_pressure, *res.cop, res.residual_norm]
    assert np.isfinite(values).all()
    assert np.isfinite(res.traction).all() and np.isfinite(res.deflection).all()
