"""The presses file and ``tactile-contact-presses`` (tactile_contact.offline.presses): each bad
file a user makes in the first hour gets a message naming the right key and the likely unit
(issue 27). The valid file and the bag path are covered by test_calibrate.py."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from tactile_contact.model.layout import load_layout
from tactile_contact.offline.presses import CalibrationError, load_presses, main_presses

ROOT = Path(__file__).resolve().parents[1]
LAYOUT = ROOT / "config" / "hexagon_patch.yaml"


@pytest.fixture(scope="module")
def patch():
    return load_layout(LAYOUT).patches[0]


def _good(n: int = 10, k: int = 72) -> dict[str, np.ndarray]:
    """Presses of a real size: compressions of up to ≈ 20 µm, 1 N, inside the patch."""
    rng = np.random.default_rng(0)
    return {
        "deflection": rng.normal(0, 5e-6, (n, k)),
        "force": np.full(n, 1.0),
        "position": rng.uniform(0, 0.02, (n, 2)),
    }


def _error(tmp_path: Path, patch, arrays: dict[str, np.ndarray]) -> str:
    path = tmp_path / "presses.npz"
    np.savez(path, **arrays)
    with pytest.raises(CalibrationError) as e:
        load_presses(path, patch)
    assert str(path) in str(e.value)
    return str(e.value)


@pytest.mark.parametrize(("scale", "unit"), [(1e3, "millimetres"), (1e6, "micrometres")])
def test_deflection_in_the_wrong_unit_names_the_likely_one(tmp_path, patch, scale, unit):
    g = _good()
    g["deflection"] = g["deflection"] * scale
    message = _error(tmp_path, patch, g)
    assert "'deflection'" in message and f"({unit} given?)" in message, message
    other = "micrometres" if unit == "millimetres" else "millimetres"
    assert other not in message, message


def test_delta_c_in_farads_is_refused_as_not_counts(tmp_path, patch):
    """ΔC of a press in farads (≈ 1e-14, what ``solve`` takes) where the file wants CDC
    counts: a fit on it came back with a gain of 0 and a layout no loader allows."""
    g = _good()
    counts = np.abs(g.pop("deflection")) * 1e6  # a few counts a reading
    g["delta_c"] = counts * 1.28e-15
    message = _error(tmp_path, patch, g)
    assert "'delta_c'" in message and "expected CDC counts" in message, message
    assert "not farads" in message, message
    g["delta_c"] = counts  # the same in counts: read
    path = tmp_path / "counts.npz"
    np.savez(path, **g)
    assert load_presses(path, patch).deflection.shape == (10, 72)


def test_a_short_force_array_is_blamed_on_force(tmp_path, patch):
    g = _good()
    g["force"] = g["force"][:8]
    message = _error(tmp_path, patch, g)
    assert "'force' has 8" in message and "10" in message, message
    assert "'deflection' must have shape" not in message, message


def test_a_short_position_array_is_blamed_on_position(tmp_path, patch):
    g = _good()
    g["position"] = g["position"][:9]
    message = _error(tmp_path, patch, g)
    assert "'position' has 9" in message, message


def test_deflection_with_other_taxels_names_the_taxel_count(tmp_path, patch):
    g = _good()
    g["deflection"] = g["deflection"][:, :70]
    message = _error(tmp_path, patch, g)
    assert "'deflection'" in message and "70" in message and "72" in message, message


def test_a_text_file_named_npz_is_said_to_be_text(tmp_path, patch):
    path = tmp_path / "presses.npz"
    path.write_text("force,x,y\n1.0,0.01,0.02\n")
    with pytest.raises(CalibrationError) as e:
        load_presses(path, patch)
    message = str(e.value)
    assert "not a readable .npz file (text:" in message, message
    assert "pickle" not in message, message


def test_presses_refuses_to_guess_the_patch(tmp_path, capsys):
    doc = yaml.safe_load(LAYOUT.read_text())
    second = yaml.safe_load(yaml.safe_dump(doc["patches"][0]))
    second["name"], second["frame_id"] = "forearm", "skin_forearm"
    for m in second["modules"]:
        m["board"] = 1
    doc["patches"].insert(0, second)
    layout = tmp_path / "two.yaml"
    layout.write_text(yaml.safe_dump(doc, sort_keys=False))
    bag = ROOT / "test" / "data" / "hexagon_session"
    out = tmp_path / "p.npz"
    assert main_presses([str(bag), str(layout), "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert "several patches (forearm, hexagon): pass --patch" in err, err
    assert not out.exists()
