"""``make demo``'s figure and printout (issue 27), on observations made here: no estimated
centre of pressure where no contact was reported (it was drawn at (0, 0)), frames without a
reported contact shown as such, titles clear of the colour bars, a ΔC scale on which the ring
of negative readings shows, and the printed force error said to be uncalibrated and 8-bit
beside a calibrated skin's figure. (The pipeline itself: test_pipeline.py.)"""

from __future__ import annotations

import types
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("matplotlib", reason="the demo's figure needs matplotlib (make setup)")

from tactile_contact.model.layout import load_layout
from tactile_contact.ros import demo

ROOT = Path(__file__).resolve().parents[1]
LAYOUT = ROOT / "config" / "hexagon_patch.yaml"


def test_the_default_layout_is_the_packages() -> None:
    assert demo.DEFAULT_LAYOUT.is_file(), demo.DEFAULT_LAYOUT


def _geometry(kind: str, shape: tuple[int, int], cell: float) -> object:
    return types.SimpleNamespace(
        origin_x=-0.013, origin_y=-0.038, width=shape[1], height=shape[0],
        cell_size_x=cell, cell_size_y=cell,
    )  # fmt: skip


@pytest.fixture(scope="module")
def observed() -> tuple[demo.DemoReport, demo.Observed]:
    """A steady 2 N press sliding along y = −17 mm; frames 12 and 13 not reported."""
    patch = load_layout(LAYOUT).patches[0]
    xy = patch.taxel_xy()
    n = 20
    stamps = 100.0 + 0.02 * np.arange(n)
    cop = np.column_stack((np.linspace(0.0, 0.03, n), np.full(n, -0.017)))
    seen_in = np.ones(n, bool)
    seen_in[[12, 13]] = False
    est = np.where(seen_in, 2.0, 0.0)
    cop_est = np.where(seen_in[:, None], cop + 2e-4, 0.0)
    dist = np.hypot(cop[:, None, 0] - xy[None, :, 0], cop[:, None, 1] - xy[None, :, 1]).min(1)
    report = demo.DemoReport(
        stamps=stamps, force_true=np.full(n, 2.0), force_est=est, cop_true=cop,
        cop_est=cop_est, latency=np.full(n, 0.004), frames_published=n, frames_simulated=n,
        in_contact=seen_in, taxel_distance=dist,
    )  # fmt: skip
    obs = demo.Observed()
    count = 0.32e-15 * 4
    rng = np.random.default_rng(1)
    for t in stamps:
        dc = rng.integers(-1, 2, len(xy)) * count * 0.3
        dc[20] = 18 * count  # the taxel under the indenter
        dc[[19, 21, 8, 30]] = -2 * count  # the ring around it: the layer bulges
        obs.taxels[t] = dc
        obs.traction[t] = np.zeros((29, 30))
        obs.deflection[t] = np.zeros((57, 59))
    obs.geometry["traction"] = _geometry("traction", (29, 30), 0.002)
    obs.geometry["deflection"] = _geometry("deflection", (57, 59), 0.001)
    return report, obs


@pytest.fixture(scope="module")
def fig(observed: tuple[demo.DemoReport, demo.Observed]) -> object:
    import matplotlib.pyplot as plt

    report, obs = observed
    f = demo.figure(report, obs, LAYOUT, "hexagon")
    f.canvas.draw()
    yield f
    plt.close(f)


def test_no_estimated_centre_where_no_contact_was_reported(fig: object) -> None:
    path_axes = fig.axes[-1]  # the centre-of-pressure path
    estimated = next(line for line in path_axes.lines if line.get_label() == "estimated")
    x, y = estimated.get_data()
    assert len(x) == 18 and not np.any(np.hypot(x, y) < 1.0), "a CoP drawn at (0, 0)"
    labels = [line.get_label() for line in path_axes.lines]
    assert "no contact reported" in labels
    force_axes = next(a for a in fig.axes if a.get_ylabel().startswith("total normal force"))
    gap = [line for line in force_axes.lines if "no contact reported" in line.get_label()]
    assert gap and len(gap[0].get_xdata()) == 2


def test_titles_clear_of_the_colour_bars(fig: object) -> None:
    renderer = fig.canvas.get_renderer()
    colorbars = [a for a in fig.axes if a.get_label() == "<colorbar>"]
    assert len(colorbars) == 3
    for ax in fig.axes:
        title = ax.title.get_window_extent(renderer)
        if ax.get_label() == "<colorbar>" or title.width == 0:
            continue
        for cb in colorbars:
            assert not title.overlaps(cb.get_window_extent(renderer)), ax.get_title()


def test_the_taxel_scale_shows_the_ring_of_negative_readings(fig: object) -> None:
    taxel_axes = next(a for a in fig.axes if a.get_title().startswith("taxel"))
    scatter = taxel_axes.collections[0]
    count = 0.32 * 4
    # −2 counts against +18: on a linear scale 0.44 of the range, almost white (0.5)
    assert scatter.norm(-2 * count) < 0.3 and scatter.norm(18 * count) > 0.95


def test_the_printed_error_says_uncalibrated_and_8_bit(observed) -> None:
    report, _ = observed
    text = "\n".join(report.summary_lines())
    assert "uncalibrated" in text and "8-bit" in text, text
    assert f"{demo.CALIBRATED_FLOAT_PERCENT} %" in text and "docs/bench/robust.md" in text
    assert "not seen: 2 frames" in text and "from the nearest taxel" in text, text
    # the CoP error is over the frames with a contact reported, not the (0, 0) of the others
    assert "centre of pressure error [mm]: median 0.28" in text, text


def test_calibrated_figures_are_the_readmes() -> None:
    readme = (ROOT / "README.md").read_text()
    assert f"{demo.CALIBRATED_FLOAT_PERCENT} % at ≥ 1 N" in readme
    assert f"8-bit readings: {demo.CALIBRATED_8BIT_PERCENT} % at ≥ 1 N" in readme
    assert f"{demo.UNCALIBRATED_WORST_PERCENT} % worst at ≥ 1 N" in readme


def test_a_run_without_summaries_is_reported_not_raised() -> None:
    """Every bundle refused (seen when a stale numba cache broke them): no summary arrives, and
    the report says so instead of raising on the median of an empty latency list."""
    obs = demo.Observed()
    obs.truth[100.0] = object()  # the simulator ran; the reconstruction published nothing
    report = demo.match(obs, 0.005)
    lines = report.summary_lines()
    assert report.frames_published == 0 and report.frames_simulated == 1
    assert lines[-1] == "no contact summary arrived: no latency or error to report"
    assert report.frame_lines() == [report.frame_lines()[0]]
