"""Shared test configuration: hypothesis profiles and real-ROS fixtures.

ROS tests talk over real DDS. Discovery stays on this machine and on a domain of its own so
that parallel runs and other ROS users do not see each other's topics.
"""

from __future__ import annotations

import os

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("ROS_DOMAIN_ID", str(17 + os.getpid() % 80))

from collections.abc import Iterator

import pytest
from hypothesis import HealthCheck, settings

settings.register_profile(
    "default",
    deadline=None,
    max_examples=60,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.register_profile("thorough", deadline=None, max_examples=1000)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "default"))


def _ros_available() -> str | None:
    """None when rclpy and the package messages import, else the reason they do not."""
    try:
        import rclpy  # noqa: F401

        from tactile_contact.msg import ContactState  # noqa: F401
    except Exception as exc:  # any import failure means: no ROS here
        return f"rclpy or tactile_contact.msg not importable ({exc!r}); run `make setup`"
    return None


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    reason = _ros_available()
    if reason is None:
        return
    if os.environ.get("TACTILE_REQUIRE_ROS") == "1":
        raise pytest.UsageError(f"TACTILE_REQUIRE_ROS=1 but {reason}")
    skip = pytest.mark.skip(reason=reason)
    for item in items:
        if "ros" in item.keywords:
            item.add_marker(skip)


@pytest.fixture(autouse=True)
def no_leftover_process() -> Iterator[None]:
    """Fail a test that leaves a process running (test/leftovers.py), after killing it: a
    stray node on the test domain would fail the tests after it instead."""
    from test.leftovers import descendants, end_leftovers

    before = descendants()
    yield
    left = end_leftovers(before)
    if left:
        pytest.fail("processes still running after the test (killed): " + "; ".join(left))


@pytest.fixture
def ros_context() -> Iterator[object]:
    """A fresh rclpy context for one test, shut down afterwards."""
    import rclpy
    from rclpy.context import Context

    context = Context()
    rclpy.init(context=context)
    try:
        yield context
    finally:
        rclpy.shutdown(context=context)


@pytest.fixture(scope="session")
def hexagon_bundle(tmp_path_factory: pytest.TempPathFactory) -> object:
    """The default patch's bundle (config/hexagon_patch.yaml), built once per test session:
    (bundle folder, PatchLayout)."""
    from pathlib import Path

    from tactile_contact.model.layout import load_layout
    from tactile_contact.offline.build import build_patch
    from tactile_contact.offline.bundle import save_bundle

    patch = load_layout(Path(__file__).resolve().parents[1] / "config/hexagon_patch.yaml").patches[
        0
    ]
    manifest, arrays = build_patch(patch)
    return save_bundle(tmp_path_factory.mktemp("hexagon") / patch.name, manifest, arrays), patch


@pytest.fixture(scope="module")
def fusion_setup(hexagon_bundle, request: pytest.FixtureRequest) -> tuple:
    """The frame-fusion tests' scene (test_temporal*.py): (bundle folder, a Reconstructor of
    it, the fine forward model of its taxels — the independent truth —, one frame's noise [m]
    per taxel: the converter's, the test module's ``NOISE`` [counts RMS], and the rounding's —
    what the node's tracker learns from frames without contact)."""
    import math

    import numpy as np

    from tactile_contact.inverse.reconstruction import Reconstructor
    from tactile_contact.model.forward import ForwardModel

    r = Reconstructor.from_bundle(hexagon_bundle[0])
    p = r.params
    truth = ForwardModel(
        r.taxel_xy,
        p["thickness"],
        p["young"],
        p["poisson"],
        fine_cell=2.5e-4,
        taxel_radius=p["taxel_radius"],
    )
    count = float(r.readings.from_counts(np.array([1.0]))[0])
    sigma = np.full(r.n_taxels, count * math.hypot(request.module.NOISE, 12**-0.5))
    return hexagon_bundle[0], r, truth, sigma


@pytest.fixture(scope="session")
def point_taxel_bundle(tmp_path_factory: pytest.TempPathFactory) -> object:
    """The default patch with ``footprint_radius: 0`` (point-value taxels, the response
    calibration finds for a point-taxel truth), built once per test session: its folder
    (test_valleys*.py)."""
    import copy
    from pathlib import Path

    import yaml

    from tactile_contact.model.layout import parse_layout
    from tactile_contact.offline.build import build_patch
    from tactile_contact.offline.bundle import save_bundle

    path = Path(__file__).resolve().parents[1] / "config" / "hexagon_patch.yaml"
    doc = copy.deepcopy(yaml.safe_load(path.read_text()))
    doc["patches"][0]["model"]["footprint_radius"] = 0.0
    manifest, arrays = build_patch(parse_layout(doc).patches[0])
    return save_bundle(tmp_path_factory.mktemp("pt") / "p", manifest, arrays)
