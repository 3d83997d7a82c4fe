"""Error messages name the key and the likely unit (issue 27): a length written in millimetres
in a layout says so. (Presses files: test_presses.py; bundles refused by the node:
test_node_output.py.)"""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from tactile_contact.model.layout import LayoutError, load_layout

ROOT = Path(__file__).resolve().parents[1]
LAYOUT = ROOT / "config" / "hexagon_patch.yaml"


@pytest.mark.parametrize(
    ("section", "key", "value", "metres"),
    [
        ("elastomer", "thickness", 2.0, "0.002"),
        ("sensor", "taxel_radius", 2, "0.002"),
        ("grid", "traction_cell", 2.0, "0.002"),
    ],
)
def test_a_length_in_millimetres_gets_the_unit_hint(tmp_path, section, key, value, metres):
    doc = yaml.safe_load(LAYOUT.read_text())
    doc["patches"][0][section][key] = value
    path = tmp_path / "layout.yaml"
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(LayoutError) as e:
        load_layout(path)
    message = str(e.value)
    assert f"{section}.{key}" in message and str(path) in message, message
    assert f"millimetres given? {value:g} mm is {metres} m" in message, message


def test_a_length_far_out_of_range_gets_no_wrong_guess(tmp_path):
    doc = yaml.safe_load(LAYOUT.read_text())
    doc["patches"][0]["elastomer"]["thickness"] = 500.0
    path = tmp_path / "layout.yaml"
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(LayoutError) as e:
        load_layout(path)
    assert "must be <= 0.1 m, got 500.0" in str(e.value) and "millimetres" not in str(e.value)
