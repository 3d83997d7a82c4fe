"""Contact summary of pressure fields."""

from __future__ import annotations

import numpy as np
import pytest

from tactile_contact.inverse.summary import summarize
from tactile_contact.model.grids import Grid
from tactile_contact.model.indenters import HertzSphere


def test_hertz_field_summary():
    g = Grid.covering([[-0.01, -0.01], [0.01, 0.01]], 2.5e-4, 0.0)
    c = g.centers()
    s = HertzSphere(6e-3)
    center = (1.2e-3, -0.7e-3)
    p = s.pressure_on_cells(c, g.half_sizes(), 2.0, center, 2.1e5, 0.5)
    out = summarize(p, c, g.cell_area)
    a = s.contact_radius(2.0, 2.1e5, 0.5)
    assert out.in_contact
    assert out.total_force == pytest.approx(2.0, rel=1e-9)
    assert out.cop == pytest.approx(center, abs=1e-6)
    # cells above 10 % of the peak: the disc of radius a·√0.99, up to the cell discretisation
    assert out.contact_area == pytest.approx(np.pi * a * a * 0.99, rel=0.03)
    assert out.peak_pressure == pytest.approx(3 * 2.0 / (2 * np.pi * a * a), rel=0.01)


def test_no_pressure_is_no_contact():
    out = summarize(np.zeros(4), np.zeros((4, 2)), 1e-6)
    assert not out.in_contact and out.cop == (0.0, 0.0) and out.total_force == 0.0


def test_negative_cells_count_in_net_force_but_not_in_cop():
    c = np.array([[0.0, 0.0], [0.01, 0.0], [0.0, 0.01]])
    out = summarize(np.array([1000.0, -200.0, 1000.0]), c, 1e-6)
    assert out.total_force == pytest.approx(1.8e-3)
    assert out.cop == pytest.approx((0.0, 0.005))
    assert out.contact_area == pytest.approx(2e-6)


def test_thresholds_are_arguments():
    c = np.zeros((3, 2))
    p = np.array([1000.0, 150.0, 50.0])
    assert summarize(p, c, 1.0).contact_area == 2.0
    assert summarize(p, c, 1.0, rel_threshold=0.0, min_pressure=0.0).contact_area == 3.0
    assert summarize(p, c, 1.0, rel_threshold=0.5).contact_area == 1.0


def test_validation():
    with pytest.raises(ValueError, match="NaN"):
        summarize([np.nan], [[0, 0]], 1.0)
    with pytest.raises(ValueError, match="centers has 2"):
        summarize([1.0], [[0, 0], [1, 1]], 1.0)
