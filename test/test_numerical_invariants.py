"""Numerical invariants that must never break (issue 6), beyond test/test_invariants.py.

Exact unit neutrality of the influence matrices under rescaling of E and of every length;
conditioning of square problems over patch size (the 0.19·L/h branch of the estimate), for
Boussinesq–Cerruti with Ψ = 0.25, and on a large grid through the FFT operator; the free
inverse of the taxel problem reproduces every reading (forward∘inverse = I on the range); the
bundle's float32 operator against float64; net-force recovery of the default on broad loads
that a minimum-norm inverse loses; finiteness for extreme parameters and readings; linearity of
the reconstruction's linear path.
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.sparse.linalg import eigsh

from tactile_contact.inverse.reconstruction import Reconstructor
from tactile_contact.model.elastic import boussinesq_matrix, love_matrix, regular_grid_operator
from tactile_contact.model.forward import ForwardModel
from tactile_contact.model.indenters import FlatPunch, HertzSphere
from tactile_contact.model.layout import parse_layout
from tactile_contact.model.sensor import rest_capacitance
from tactile_contact.offline.build import build_patch, free_inverse
from tactile_contact.offline.bundle import save_bundle

ROOT = Path(__file__).resolve().parents[1]
DOC = yaml.safe_load((ROOT / "config" / "hexagon_patch.yaml").read_text())
H, E, NU = 2e-3, 2.1e5, 0.5


def _patch(**sections: dict):
    doc = copy.deepcopy(DOC)
    for sec, kv in sections.items():
        doc["patches"][0].setdefault(sec, {}).update(kv)
    return parse_layout(doc).patches[0]


def _recon(tmp: pytest.TempPathFactory, **sections: dict) -> Reconstructor:
    m, a = build_patch(_patch(**sections))
    return Reconstructor.from_bundle(save_bundle(tmp.mktemp("num") / "p", m, a))


def _square(n: int, pitch: float) -> tuple[np.ndarray, np.ndarray]:
    c = (np.arange(n) - (n - 1) / 2) * pitch
    xx, yy = np.meshgrid(c, c)
    return np.column_stack([xx.ravel(), yy.ravel()]), np.full(2, pitch / 2)


def _estimate(d: float, length: float) -> float:
    return max(0.94 * H / d, 0.19 * length / H)


@pytest.fixture(scope="module")
def default(tmp_path_factory: pytest.TempPathFactory) -> Reconstructor:
    return _recon(tmp_path_factory)


@pytest.fixture(scope="module")
def pinv(tmp_path_factory: pytest.TempPathFactory) -> Reconstructor:
    return _recon(tmp_path_factory, solver={"method": "pinv", "refine": "none"})


@pytest.fixture(scope="module")
def fine(default: Reconstructor) -> ForwardModel:
    p = default.params
    return ForwardModel(default.taxel_xy, p["thickness"], p["young"], p["poisson"], 2.5e-4, 2e-3)


# --- unit neutrality ---------------------------------------------------------------------


@settings(max_examples=15)
@given(
    length=st.floats(1e-3, 1e3),
    young=st.floats(1e-3, 1e4),
    nu=st.sampled_from([0.0, 0.3, 0.49, 0.5]),
)
def test_matrices_scale_exactly_with_lengths_and_modulus(
    length: float, young: float, nu: float
) -> None:
    # u = p·L/E·f(shape, ν): rescaling every length by s and E by k scales the Love matrix
    # [m/Pa] by s/k and the B-C matrix [m/N] by 1/(s·k). Any hidden absolute constant (a
    # tolerance in metres, a cut-off radius) breaks this.
    pts, half = _square(6, 1e-3)
    taxels = pts[::5] + np.array([3e-4, -2e-4])
    ref = love_matrix(taxels, pts, half, H, E, nu)
    got = love_matrix(length * taxels, length * pts, length * half, length * H, young * E, nu)
    np.testing.assert_allclose(got * young / length, ref, rtol=1e-10, atol=1e-12 * abs(ref).max())
    ref = boussinesq_matrix(taxels, pts, 1e-6, H, E, nu, 0.25)
    got = boussinesq_matrix(
        length * taxels, length * pts, length**2 * 1e-6, length * H, young * E, nu, 0.25
    )
    np.testing.assert_allclose(got * young * length, ref, rtol=1e-10, atol=1e-12 * abs(ref).max())


# --- conditioning ------------------------------------------------------------------------


@pytest.mark.parametrize("n", [8, 24, 32])
def test_square_love_conditioning_follows_patch_size(n: int) -> None:
    # The 0.19·L/h branch of κ ≈ max(0.94·h/d, 0.19·L/h): measured 0.99–1.33 × the estimate.
    pts, half = _square(n, H)
    kappa = np.linalg.cond(love_matrix(pts, pts, half, H, E, NU))
    est = _estimate(H, n * H)
    assert est / 1.6 <= kappa <= 1.6 * est, (kappa, est)


@pytest.mark.parametrize("ratio", [0.05, 0.25, 1.0, 2.0, 3.0])
def test_square_boussinesq_with_constant_psi_is_well_conditioned(ratio: float) -> None:
    # DESIGN.md §2: B-C square problems have κ ≤ 50. With the fitted Ψ this fails near
    # d = 1.94·h, where Ψ changes sign (docs/bench/stability.md §2); Ψ = 0.25 has no zero.
    d = ratio * H
    pts, _ = _square(12, d)
    kappa = np.linalg.cond(boussinesq_matrix(pts, pts, d * d, H, E, NU, 0.25))
    assert 1.0 <= kappa <= 50.0


def test_large_regular_grid_is_positive_definite_and_in_the_band() -> None:
    # 4096 cells through the FFT operator: the symmetric matrix stays positive definite and
    # its κ = λmax/λmin stays in the band (measured 11.4 against 12.2).
    n = 64
    op = regular_grid_operator(n, n, H, H, H, E, NU).as_linear_operator()
    top = eigsh(op, k=1, which="LA", tol=1e-6, return_eigenvectors=False)[0]
    low = eigsh(op, k=1, which="SA", tol=1e-6, return_eigenvectors=False)[0]
    assert low > 0
    est = _estimate(H, n * H)
    assert est / 1.6 <= top / low <= 1.6 * est


# --- inverse and forward -----------------------------------------------------------------


def test_free_inverse_of_the_taxel_problem_reproduces_every_reading(pinv: Reconstructor) -> None:
    # K = 72 < N = 568 and C has full row rank (κ ≈ 1.5 over its 72 singular values), so
    # C·C⁺ = I_K: forward∘inverse is the identity on the data. Through the bundle's float32
    # operator the identity holds to float32 rounding.
    c = pinv.forward
    exact, _ = free_inverse(_patch(solver={"method": "pinv"}), c, None)
    np.testing.assert_allclose(c @ exact, np.eye(len(c)), atol=1e-9)
    single = np.asarray(pinv.bundle["inverse"], dtype=np.float64)
    assert np.abs(c @ single - np.eye(len(c))).max() <= 1e-5


def test_bundle_float32_online_product_is_within_1e_5_of_float64(
    default: Reconstructor, fine: ForwardModel
) -> None:
    exact, _ = free_inverse(_patch(), default.forward, None)
    single = np.asarray(default.bundle["inverse"])
    assert single.dtype == np.float32
    for k in (3, 40, 60):
        d = fine.compression(HertzSphere(3e-3), 1.0, default.taxel_xy[k])
        q64 = exact @ d
        q32 = (single @ d.astype(np.float32)).astype(np.float64)
        assert np.abs(q32 - q64).max() <= 1e-5 * np.abs(q64).max()


# --- net force ---------------------------------------------------------------------------


@pytest.mark.parametrize("radius", [3e-3, 6e-3])
def test_default_keeps_the_net_force_a_minimum_norm_inverse_loses(
    default: Reconstructor, pinv: Reconstructor, fine: ForwardModel, radius: float
) -> None:
    # ν = 0.5: a broad load barely compresses the layer, so the pseudo-inverse returns little
    # net force (measured −0.03 and 0.25 N of 2 N for 3 and 6 mm punches over taxel 40). The
    # default (two-pass NNLS + Tikhonov) recovered 1.83 and 1.26 N, CoP within 0.8 mm; the
    # bounds leave room for tuning but not for falling back to the minimum-norm behaviour.
    centre = default.taxel_xy[40]
    d = fine.compression(FlatPunch(radius), 2.0, centre)
    assert abs(pinv.solve_deflection(d).total_force) < 0.4
    res = default.solve_deflection(d)
    assert res.in_contact and 1.0 <= res.total_force <= 3.0
    assert np.hypot(*np.subtract(res.cop, centre)) < 1.5e-3


def test_default_force_of_a_compact_load_over_a_taxel(
    default: Reconstructor, fine: ForwardModel
) -> None:
    # The 12 mm sphere at 1 N over a taxel, clean data: measured 1.006 N, CoP 0.02 mm.
    centre = default.taxel_xy[40]
    res = default.solve_deflection(fine.compression(HertzSphere(6e-3), 1.0, centre))
    assert res.total_force == pytest.approx(1.0, rel=0.15)
    assert np.hypot(*np.subtract(res.cop, centre)) < 0.5e-3


# --- finiteness --------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("h", "young", "d_over_h"),
    [(2e-4, 1e3, 1.0), (1e-2, 1e9, 1.0), (H, E, 0.01), (H, E, 10.0), (H, 1e-3, 1.0)],
)
def test_extreme_parameters_give_finite_well_posed_square_problems(
    h: float, young: float, d_over_h: float
) -> None:
    pts, half = _square(10, d_over_h * h)
    c = love_matrix(pts, pts, half, h, young, NU)
    assert np.isfinite(c).all()
    assert np.linalg.cond(c) < 100


def test_no_nan_or_inf_for_extreme_capacitance_readings(default: Reconstructor) -> None:
    p = default.params
    c0 = float(rest_capacitance(p["thickness"], p["epsilon_r"], p["area"]))
    rng = np.random.default_rng(5)
    frames = [
        np.full(default.n_taxels, -c0 * (1 - 1e-9)),  # the layer at (almost) infinite height
        np.full(default.n_taxels, 1e3 * c0),  # electrodes almost touching
        rng.uniform(-c0, 1e3 * c0, default.n_taxels),
        np.where(rng.random(default.n_taxels) < 0.3, np.nan, 1e-13),  # NaN = excluded
        np.full(default.n_taxels, -2 * c0),  # impossible: every taxel excluded
    ]
    for dc in frames:
        res = default.solve(dc)
        values = [res.total_force, res.contact_area, res.peak_pressure, *res.cop]
        assert np.isfinite(values).all()
        assert np.isfinite(res.traction).all() and np.isfinite(res.deflection).all()


# --- linearity of the linear path --------------------------------------------------------


@settings(max_examples=10)
@given(alpha=st.floats(-3.0, 3.0), beta=st.floats(-3.0, 3.0))
def test_the_pinv_path_is_linear(pinv: Reconstructor, alpha: float, beta: float) -> None:
    rng = np.random.default_rng(0)
    a, b = rng.normal(0, 2e-5, (2, pinv.n_taxels))
    mix = alpha * a + beta * b
    if np.abs(mix).max() <= pinv.contact_threshold:
        return  # below the contact test: no solve, by design
    ra, rb = pinv.solve_deflection(a), pinv.solve_deflection(b)
    rm = pinv.solve_deflection(mix)
    scale = max(np.abs(rm.traction).max(), np.abs(ra.traction).max(), 1.0)
    np.testing.assert_allclose(
        rm.traction,
        alpha * ra.traction + beta * rb.traction,
        atol=1e-5 * scale * (1 + abs(alpha) + abs(beta)),
    )
    np.testing.assert_allclose(
        rm.deflection,
        alpha * ra.deflection + beta * rb.deflection,
        atol=1e-5 * np.abs(rm.deflection).max() * (1 + abs(alpha) + abs(beta)),
    )
