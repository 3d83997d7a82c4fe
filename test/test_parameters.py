"""Every key in config/*.yaml is a parameter its node declares, with the declared type, and
every declared parameter is in the README's parameter table with unit and range (issue 18).

The nodes are the real ones, constructed with the file's values as overrides: rclpy refuses a
value of the wrong type at declaration, and silently ignores a key nobody declares — which is
what this test is for.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

pytestmark = pytest.mark.ros

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = {
    "skin_driver": ROOT / "config" / "skin_driver.yaml",
    "contact_reconstruction": ROOT / "config" / "contact_reconstruction.yaml",
    "skin_simulator": ROOT / "config" / "skin_simulator.yaml",
}
# Values that keep a constructed node off hardware; the file's own value is type-checked too.
SAFE = {
    "skin_driver": {"autostart": False},
    "skin_simulator": {"interface": "virtual", "channel": "test_parameters"},
}


def _file_parameters(node: str) -> dict:
    doc = yaml.safe_load(CONFIGS[node].read_text())
    assert list(doc) == [node], f"{CONFIGS[node]}: top-level key must be the node name"
    return doc[node]["ros__parameters"]


def _make(node: str, context, overrides):
    from tactile_contact.nodes.contact_reconstruction import ContactReconstructionNode
    from tactile_contact.nodes.skin_driver import SkinDriver
    from tactile_contact.nodes.skin_simulator import SkinSimulatorNode

    cls = {
        "skin_driver": SkinDriver,
        "contact_reconstruction": ContactReconstructionNode,
        "skin_simulator": SkinSimulatorNode,
    }[node]
    return cls(context=context, parameter_overrides=overrides)


@pytest.fixture(scope="module")
def bundles(tmp_path_factory):
    from tactile_contact.build import build_layout

    out = tmp_path_factory.mktemp("bundles")
    build_layout(ROOT / "config" / "hexagon_patch.yaml", out, jobs=1)
    return out


@pytest.mark.parametrize("node", sorted(CONFIGS))
def test_every_config_key_is_a_declared_parameter_of_its_type(node, ros_context, bundles):
    from rclpy.parameter import Parameter

    values = _file_parameters(node)
    # Each file value once as given (type check at declaration), then the safe ones.
    overrides = [Parameter(k, value=v) for k, v in values.items()]
    first = _make(node, ros_context, overrides + _safe(node, bundles))
    try:
        declared = set(first._parameters)
        unknown = sorted(set(values) - declared)
        assert not unknown, f"{CONFIGS[node]}: keys no parameter of {node} has: {unknown}"
        for key, value in values.items():
            got = first.get_parameter(key).value
            if key not in SAFE.get(node, {}) and key != "bundles_dir":
                assert got == value, (key, got, value)
    finally:
        first.destroy_node()


def _safe(node, bundles):
    from rclpy.parameter import Parameter

    safe = dict(SAFE.get(node, {}))
    if node == "contact_reconstruction":
        safe["bundles_dir"] = str(bundles)
    return [Parameter(k, value=v) for k, v in safe.items()]


def test_a_mistyped_key_is_refused(ros_context):
    from rclpy.exceptions import InvalidParameterTypeException
    from rclpy.parameter import Parameter

    with pytest.raises(InvalidParameterTypeException):
        _make(
            "skin_simulator",
            ros_context,
            [Parameter("period_ms", value="fifty"), *_safe("skin_simulator", None)],
        )


def _readme_rows() -> dict[str, dict[str, list[str]]]:
    """node → parameter → the table row's cells, from the README's parameter tables."""
    text = (ROOT / "README.md").read_text()
    tables: dict[str, dict[str, list[str]]] = {}
    node = None
    for line in text.splitlines():
        m = re.match(r"### `(\w+)`", line)
        if m:
            node = m.group(1)
            continue
        m = re.match(r"\| `(\w+)` \|(.*)\|$", line)
        if node and m:
            tables.setdefault(node, {})[m.group(1)] = [c.strip() for c in m.group(2).split("|")]
    return tables


@pytest.mark.parametrize("node", sorted(CONFIGS))
def test_every_declared_parameter_is_documented(node, ros_context, bundles):
    rows = _readme_rows().get(node, {})
    made = _make(node, ros_context, _safe(node, bundles))
    try:
        for name in sorted(made._parameters):
            if name == "use_sim_time":
                continue
            assert name in rows, f"README.md: parameter {node}.{name} missing from its table"
            typ, _default, unit, rng, meaning = rows[name]
            descriptor = made.describe_parameter(name)
            has_range = bool(descriptor.integer_range or descriptor.floating_point_range)
            assert meaning and typ and unit, (node, name, rows[name])
            if has_range:
                assert "…" in rng, f"README.md: {node}.{name} has a range; the table says {rng!r}"
    finally:
        made.destroy_node()
