"""Every key in config/*.yaml is a parameter its node declares, with the declared type, and
every declared parameter is in the README's parameter table with its type, default, unit and
range (issue 18).

The files are loaded as ``ros2 run … --ros-args --params-file FILE`` and ``ros2 launch`` load
them: parsed by rcl into the context's arguments and applied by the real node at declaration.
rclpy refuses a value of the wrong type there, and silently ignores a key nobody declares —
which is what this test is for. A tampered copy of each file shows that both are caught.
"""

from __future__ import annotations

import math
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
# Values that keep a constructed node off hardware (they replace the file's value, whose type is
# still compared with the declared one).
SAFE = {
    "skin_driver": {"autostart": False},
    "skin_simulator": {"interface": "virtual", "channel": "test_parameters"},
    "contact_reconstruction": {},  # + bundles_dir: a folder of freshly built bundles
}
README_TYPES = {
    "BOOL": "bool",
    "INTEGER": "int",
    "DOUBLE": "float",
    "STRING": "str",
    "STRING_ARRAY": "string[]",
}


def _node_class(node: str) -> type:
    from tactile_contact.ros.contact_reconstruction import ContactReconstructionNode
    from tactile_contact.ros.skin_driver import SkinDriver
    from tactile_contact.ros.skin_simulator import SkinSimulatorNode

    return {
        "skin_driver": SkinDriver,
        "contact_reconstruction": ContactReconstructionNode,
        "skin_simulator": SkinSimulatorNode,
    }[node]


def _safe(node: str, bundles: Path) -> dict[str, object]:
    safe = dict(SAFE[node])
    if node == "contact_reconstruction":
        safe["bundles_dir"] = str(bundles)
    return safe


@pytest.fixture(scope="module")
def bundles(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from tactile_contact.offline.build import build_layout

    out = tmp_path_factory.mktemp("bundles")
    build_layout(ROOT / "config" / "hexagon_patch.yaml", out, jobs=1)
    return out


def config_problems(node: str, path: Path, bundles: Path) -> list[str]:
    """What is wrong with parameter file ``path`` for ``node``, loaded with --params-file."""
    import rclpy
    from rclpy.context import Context
    from rclpy.exceptions import InvalidParameterTypeException
    from rclpy.parameter import Parameter

    doc = yaml.safe_load(path.read_text())
    if list(doc) != [node] or list(doc[node]) != ["ros__parameters"]:
        return [f"{path}: must hold only {node}: ros__parameters: (found {list(doc)})"]
    in_file = doc[node]["ros__parameters"]
    safe = _safe(node, bundles)
    context = Context()
    rclpy.init(args=["--ros-args", "--params-file", str(path)], context=context)
    try:
        try:
            made = _node_class(node)(
                context=context,
                parameter_overrides=[Parameter(k, value=v) for k, v in safe.items()],
            )
        except InvalidParameterTypeException as exc:
            return [f"{path}: {exc}"]
        try:
            problems = []
            # rcl read every key of the file (a key it cannot parse would be missing here).
            missing = set(in_file) - set(made._parameter_overrides)
            if missing:
                problems.append(f"{path}: rcl did not read {sorted(missing)}")
            for key, value in in_file.items():
                if key not in made._parameters:
                    problems.append(f"{path}: {key!r} is not a parameter of {node}")
                    continue
                declared = made.get_parameter(key)
                given = Parameter(key, value=value).type_
                if given != declared.type_:
                    problems.append(
                        f"{path}: {key} is {given.name}, declared {declared.type_.name}"
                    )
                elif key not in safe and declared.value != value:
                    problems.append(
                        f"{path}: {key} = {value!r} but the node has {declared.value!r}"
                    )
            return problems
        finally:
            made.destroy_node()
    finally:
        rclpy.shutdown(context=context)


@pytest.mark.parametrize("node", sorted(CONFIGS))
def test_every_config_key_is_a_declared_parameter_of_its_type(node: str, bundles: Path) -> None:
    assert config_problems(node, CONFIGS[node], bundles) == []


@pytest.mark.parametrize("node", sorted(CONFIGS))
def test_an_unknown_or_mistyped_key_is_caught(node: str, bundles: Path, tmp_path: Path) -> None:
    doc = yaml.safe_load(CONFIGS[node].read_text())
    params = doc[node]["ros__parameters"]
    typo = dict(params, no_such_parameter=1.0)
    path = tmp_path / "typo.yaml"
    path.write_text(yaml.safe_dump({node: {"ros__parameters": typo}}))
    problems = config_problems(node, path, bundles)
    assert len(problems) == 1 and "no_such_parameter" in problems[0], problems

    # An integer parameter written as a float (or the other way round) is refused.
    key = next(k for k, v in params.items() if isinstance(v, (int, float)) and k not in SAFE[node])
    value = params[key]
    wrong = dict(params, **{key: float(value) if isinstance(value, int) else int(value)})
    path.write_text(yaml.safe_dump({node: {"ros__parameters": wrong}}))
    problems = config_problems(node, path, bundles)
    assert len(problems) == 1 and key in problems[0], problems


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
        if line.startswith("## "):
            node = None
        m = re.match(r"\| `(\w+)` \|(.*)\|$", line)
        if node and m:
            tables.setdefault(node, {})[m.group(1)] = [c.strip() for c in m.group(2).split("|")]
    return tables


def _readme_value(text: str) -> object:
    """A default as the table writes it: "text", true/false, [] or a number (2e-13 too)."""
    if text.startswith('"') and text.endswith('"'):
        return text[1:-1]
    if text in ("true", "false"):
        return text == "true"
    if text == "[]":
        return []
    try:
        return int(text)
    except ValueError:
        try:
            return float(text)
        except ValueError:
            return text


def _close(a: float, b: float) -> bool:
    return math.isclose(float(a), float(b), rel_tol=1e-9, abs_tol=0.0)


def _row_problems(node: str, name: str, row: list[str], made: object, default: object) -> list[str]:
    typ, shown_default, unit, rng, meaning = row
    where = f"README.md {node}.{name}"
    descriptor = made.describe_parameter(name)  # type: ignore[attr-defined]
    declared_type = made.get_parameter(name).type_.name  # type: ignore[attr-defined]
    problems = []
    if not meaning:
        problems.append(f"{where}: no meaning")
    if typ != README_TYPES[declared_type]:
        problems.append(f"{where}: type {typ!r}, declared {declared_type}")
    shown = _readme_value(shown_default)
    if isinstance(default, float):
        if not isinstance(shown, (int, float)) or not _close(shown, default):
            problems.append(f"{where}: default {shown_default!r}, declared {default!r}")
    elif shown != default:
        problems.append(f"{where}: default {shown_default!r}, declared {default!r}")
    m = re.search(r"\[([^\]]+)\]$", descriptor.description)
    if unit != (m.group(1) if m else "–"):
        problems.append(f"{where}: unit {unit!r}, declared {descriptor.description!r}")
    bounds = list(descriptor.integer_range) + list(descriptor.floating_point_range)
    if bounds:
        lo, _, hi = rng.partition("…")
        try:
            ok = _close(lo, bounds[0].from_value) and _close(hi, bounds[0].to_value)
        except ValueError:
            ok = False
        if not ok:
            b = bounds[0]
            problems.append(f"{where}: range {rng!r}, declared {b.from_value}…{b.to_value}")
    elif descriptor.additional_constraints:
        if rng != descriptor.additional_constraints:
            problems.append(f"{where}: range {rng!r}, declared {descriptor.additional_constraints}")
    elif rng != "–":
        problems.append(f"{where}: range {rng!r}, but none is declared")
    return problems


@pytest.mark.parametrize("node", sorted(CONFIGS))
def test_every_declared_parameter_is_documented(
    node: str, ros_context: object, bundles: Path
) -> None:
    from rclpy.parameter import Parameter

    rows = _readme_rows().get(node, {})
    safe = _safe(node, bundles)
    made = _node_class(node)(
        context=ros_context,
        parameter_overrides=[Parameter(k, value=v) for k, v in safe.items()],
    )
    try:
        # The declared default: the value without overrides (the file's value for the keys the
        # test had to override: the files hold the defaults, test above).
        in_file = yaml.safe_load(CONFIGS[node].read_text())[node]["ros__parameters"]
        problems = []
        declared = sorted(set(made._parameters) - {"use_sim_time"})
        for name in declared:
            if name not in rows:
                problems.append(f"README.md: parameter {node}.{name} missing from its table")
                continue
            default = in_file[name] if name in safe else made.get_parameter(name).value
            if isinstance(default, (list, tuple)):
                default = list(default)
            problems += _row_problems(node, name, rows[name], made, default)
        extra = sorted(set(rows) - set(declared))
        if extra:
            problems.append(f"README.md: {node} table lists undeclared {extra}")
        assert problems == [], "\n".join(problems)
    finally:
        made.destroy_node()
