"""Patch layout loading and validation: the shipped configs load, every error names file, key
path and problem."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
import yaml

from tactile_contact.model.layout import LayoutError, load_layout, parse_layout
from tactile_contact.model.modules import place_channels, split_taxel_id

ROOT = Path(__file__).resolve().parents[1]
HEXAGON = ROOT / "config" / "hexagon_patch.yaml"
ROBOT = ROOT / "config" / "robot_skin.yaml"


@pytest.fixture
def doc() -> dict:
    return yaml.safe_load(HEXAGON.read_text())


def test_hexagon_patch_geometry():
    lay = load_layout(HEXAGON)
    (p,) = lay.patches
    assert p.name == "hexagon" and p.frame_id == "skin_hexagon"
    xy = p.taxel_xy()
    assert xy.shape == (72, 2)
    d = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1))
    np.fill_diagonal(d, np.inf)
    # the paper's patch: every taxel has a neighbour at the 5.5 mm pitch, none closer
    assert d.min() == pytest.approx(5.485e-3, abs=2e-5)
    assert np.all(d.min(axis=1) < 5.6e-3)
    # the hexagon's centre is shared by all six triangles: (16.732, -9.660) mm
    assert np.allclose(xy.mean(axis=0), [16.732e-3, -9.660e-3], atol=1e-5)
    ids = p.taxel_ids()
    assert len(set(ids.tolist())) == 72
    assert {split_taxel_id(int(t))[1] for t in ids} == set(range(6))
    e, s = p.elastomer, p.sensor
    assert (e.thickness, e.young, e.poisson) == (2e-3, 2.1e5, 0.5)
    assert (s.epsilon_r, s.taxel_radius, s.farad_per_count, s.no_load, s.shift) == (
        4.37,
        2e-3,
        0.32e-15,
        240,
        2,
    )
    assert p.grid.traction_cell == 2e-3


def test_taxel_order_matches_module_placement():
    p = load_layout(HEXAGON).patches[0]
    m = p.modules[1]
    expect = place_channels(m.module_type, m.position, m.rotation_deg, m.mirrored)
    np.testing.assert_allclose(p.taxel_xy()[12:24], expect)


def test_robot_skin_has_two_patches_and_pads_are_not_taxels():
    lay = load_layout(ROBOT)
    assert len(lay.patches) >= 2
    palm = next(p for p in lay.patches if any(m.type == "icub_v2_10pad" for m in p.modules))
    n_icub = sum(m.type == "icub_v2_10pad" for m in palm.modules)
    assert palm.valid_mask().sum() <= len(palm.modules) * 12 - 2 * n_icub
    assert len(palm.taxel_xy()) == palm.valid_mask().sum()
    assert lay.patch(palm.name) is palm


def test_disabled_channels_drop_out(doc):
    doc["patches"][0]["modules"][0]["disabled_channels"] = [0, 5]
    p = parse_layout(doc, "x.yaml").patches[0]
    assert len(p.taxel_xy()) == 70
    assert p.valid_mask().sum() == 70 and len(p.channel_xy()) == 72


def test_hashes_separate_geometry_from_parameters(doc):
    a = parse_layout(doc).patches[0]
    d2 = copy.deepcopy(doc)
    d2["patches"][0]["solver"]["tikhonov"] = 0.05
    b = parse_layout(d2).patches[0]
    assert a.layout_hash() == b.layout_hash() and a.parameter_hash() != b.parameter_hash()
    d3 = copy.deepcopy(doc)
    d3["patches"][0]["modules"][0]["rotation_deg"] = 61
    c = parse_layout(d3).patches[0]
    assert a.layout_hash() != c.layout_hash()
    d4 = copy.deepcopy(doc)
    d4["patches"][0]["frame_id"] = "other"
    assert parse_layout(d4).patches[0].parameter_hash() == a.parameter_hash()


def test_defaults_fill_missing_sections():
    p = parse_layout(
        {
            "patches": [
                {
                    "name": "p",
                    "modules": [
                        {"type": "roboskin12", "board": 1, "triangle": 2, "position": [0, 0]}
                    ],
                }
            ]
        }
    ).patches[0]
    assert p.frame_id == "p" and p.elastomer.poisson == 0.5 and p.solver.method == "nnls_tikhonov"
    assert p.solver.tikhonov == 0.1 and p.solver.tsvd_rank == "discrepancy"
    assert p.sensor.area == pytest.approx(np.pi * 4e-6)


@pytest.mark.parametrize(
    ("key", "value", "parsed"),
    [("tikhonov", "gcv", "gcv"), ("tikhonov", "1e-1", 0.1), ("tsvd_rank", "all", None)],
)
def test_regularisation_parameters_take_a_number_or_a_rule(key, value, parsed):
    doc = yaml.safe_load(HEXAGON.read_text())
    doc["patches"][0]["solver"][key] = value
    assert getattr(parse_layout(doc).patches[0].solver, key) == parsed


def _set(doc, path, value):
    node = doc
    for k in path[:-1]:
        node = node[k]
    if value is _DEL:
        del node[path[-1]]
    else:
        node[path[-1]] = value


_DEL = object()
M = ("patches", 0, "modules")


@pytest.mark.parametrize(
    ("path", "value", "message"),
    [
        (
            (*M, 3, "type"),
            "foo",
            "patches[0].modules[3].type: unknown module type 'foo' (known: "
            "icub_palm_left_0, icub_palm_left_1, ",
        ),
        ((*M, 2, "triangle"), 1, "patches[0].modules[2]: duplicate CAN address board 0 triangle 1"),
        ((*M, 2, "position"), [0.0003, 0.0], "patches[0].modules[4]: overlapping taxels"),
        (
            ("patches", 0, "model", "psi"),
            0.25,
            "patches[0].model.psi: only the boussinesq model has a Ψ (kind is love)",
        ),
        # 3 mm apart: nothing coincides, but 2 mm-radius electrodes would share skin.
        ((*M, 2, "position"), [0.003, 0.0], "electrodes of radius 2 mm overlap below 4 mm"),
        ((*M, 0, "board"), 16, "patches[0].modules[0].board: must be <= 15, got 16"),
        ((*M, 0, "position"), [0.0], "patches[0].modules[0].position: expected [x, y]"),
        ((*M, 0, "colour"), "red", "patches[0].modules[0].colour: unknown key"),
        ((*M, 0, "disabled_channels"), [12], "disabled_channels: expected a list of channels"),
        (
            ("patches", 0, "elastomer", "thickness"),
            -0.002,
            "patches[0].elastomer.thickness: must be > 0.0, got -0.002",
        ),
        (
            ("patches", 0, "elastomer", "poisson"),
            0.51,
            "patches[0].elastomer.poisson: must be <= 0.5, got 0.51",
        ),
        (("patches", 0, "elastomer", "young"), "soft", "elastomer.young: expected a number"),
        (("patches", 0, "elastomer", "young"), 0.21, "expected pascals (MPa given? 0.21 MPa"),
        (("patches", 0, "elastomer", "young"), 2.1e11, "stiffer than any skin elastomer"),
        ((*M, 0, "type"), ["roboskin12"], "modules[0].type: unknown"),
        (("patches", 0, "grid", "mask"), ["hull"], "grid.mask: unknown value ['hull']"),
        (("patches", 0, "elastomer", "young"), float("nan"), "must be finite"),
        (("patches", 0, "sensor", "area"), 1e-5, "sensor.area: give either taxel_radius or area"),
        (("patches", 0, "grid", "mask"), "circle", "grid.mask: unknown value 'circle'"),
        (("patches", 0, "model", "kind"), "fem", "model.kind: unknown value 'fem'"),
        (("patches", 0, "solver", "method"), "magic", "solver.method: unknown value 'magic'"),
        (("patches", 0, "name"), "has space", "patches[0].name: expected a name of ASCII"),
        # names rclpy refuses in a topic (the bringup crashed on them after the build)
        (("patches", 0, "name"), "left-arm", "patches[0].name: expected a name of ASCII"),
        (("patches", 0, "name"), "1patch", "starting with a letter"),
        (("patches", 0, "name"), "bras_\u00e9", "got 'bras_\u00e9'"),
        (("patches", 0, "name"), 12, "got 12 (a string: quote it)"),
        (("patches", 0, "bus"), 1, "patches[0].bus: expected a bus name of ASCII"),
        (("patches", 0, "frame_id"), "/skin", "frame_id: expected a tf2 frame name (not empty"),
        (("patches", 0, "frame_id"), "skin hexagon", "frame_id: expected a tf2 frame name without"),
        (("patches", 0, "modules"), [], "patches[0].modules: expected a non-empty list"),
        (("patches", 0, "extra"), 1, "patches[0].extra: unknown key"),
        (("schema_version",), 2, "schema_version: unsupported version 2"),
        (("patches",), _DEL, "patches: expected a non-empty list"),
    ],
)
def test_errors_name_file_key_and_problem(doc, tmp_path, path, value, message):
    _set(doc, path, value)
    f = tmp_path / "x.yaml"
    f.write_text(yaml.safe_dump(doc))
    with pytest.raises(LayoutError) as exc:
        load_layout(f)
    assert str(exc.value).startswith(f"{f}: ")
    assert message in str(exc.value)


def test_boussinesq_psi_checked(doc):
    doc["patches"][0]["model"] = {"kind": "boussinesq", "psi": "wrong"}
    with pytest.raises(LayoutError, match=r"model\.psi: expected 'exact' or a positive number"):
        parse_layout(doc, "x.yaml")
    doc["patches"][0]["model"]["psi"] = 0.25
    assert parse_layout(doc).patches[0].model.psi == 0.25


def test_duplicate_address_across_patches_and_names(doc):
    second = copy.deepcopy(doc["patches"][0])
    second["name"] = "other"
    doc["patches"].append(second)
    with pytest.raises(LayoutError, match=r"patches\[1\]\.frame_id: frame 'skin_hexagon' is also"):
        parse_layout(doc, "x.yaml")  # (a copied patch keeps its frame: drawn on the first)
    # side by side in one frame (one sheet on two buses): fine
    beside = copy.deepcopy(second)
    beside["bus"] = "can9"
    for m in beside["modules"]:
        m["position"] = [m["position"][0] + 0.1, m["position"][1]]
    assert len(parse_layout({**doc, "patches": [doc["patches"][0], beside]}).patches) == 2
    second["frame_id"] = "skin_other"
    with pytest.raises(LayoutError, match=r"patches\[1\]\.modules\[0\]: duplicate CAN address"):
        parse_layout(doc, "x.yaml")
    second["name"] = "hexagon"
    with pytest.raises(LayoutError, match=r"patches\[1\]\.name: duplicate patch name"):
        parse_layout(doc, "x.yaml")


def test_unreadable_and_invalid_yaml(tmp_path):
    with pytest.raises(LayoutError, match="cannot read"):
        load_layout(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("patches: [\n  - {name: x\n")
    with pytest.raises(LayoutError, match=r"bad\.yaml: invalid YAML"):
        load_layout(bad)
    top = tmp_path / "list.yaml"
    top.write_text("- 1\n")
    with pytest.raises(LayoutError, match="expected a mapping"):
        load_layout(top)


def test_a_key_given_twice_and_text_not_utf8_are_refused_with_their_line(tmp_path):
    """PyYAML keeps the last of a key given twice (a second ``modules:`` made a 6-module
    patch 1 module) and a Latin-1 comment raised UnicodeDecodeError: both are LayoutErrors
    naming the file and the line."""
    text = HEXAGON.read_text()
    twice = tmp_path / "twice.yaml"
    twice.write_text(text.replace("    modules:", "    modules: []\n    modules:", 1))
    with pytest.raises(LayoutError, match=r"twice\.yaml.*'modules' given twice.*line \d+"):
        load_layout(twice)
    latin = tmp_path / "latin.yaml"
    latin.write_bytes(text.encode() + "# r\u00e9sum\u00e9\n".encode("latin-1"))
    n = text.count("\n") + 1
    with pytest.raises(LayoutError, match=rf"latin\.yaml:{n}: not UTF-8"):
        load_layout(latin)
    assert len(load_layout(HEXAGON).patches[0].modules) == 6  # (the file itself loads)


def test_merge_keys_work_and_a_key_they_override_is_not_a_duplicate(tmp_path):
    """``<<: *defaults`` (YAML merge keys, which PyYAML's safe loader reads) broke when the
    duplicate-key check was added ("could not determine a constructor for the tag ...merge");
    a key given beside a merge overrides the merged one; twice beside it is still an error."""
    base = """patches:
  - &p1
    name: p
    modules:
      - {type: roboskin12, board: 0, triangle: 0, position: [0.0, 0.0]}
    elastomer: {thickness: 0.003}
  - <<: *p1
    name: q
    bus: can2
"""
    merged = tmp_path / "merged.yaml"
    merged.write_text(base)
    lay = load_layout(merged)
    assert [(q.name, q.bus) for q in lay.patches] == [("p", ""), ("q", "can2")]
    assert lay.patches[1].elastomer == lay.patches[0].elastomer
    twice = tmp_path / "twice.yaml"
    twice.write_text(base + "    bus: can3\n")
    with pytest.raises(LayoutError, match=r"'bus' given twice"):
        load_layout(twice)


def test_positions_in_millimetres_are_refused_before_the_build(tmp_path):
    """A layout written in millimetres loaded, then its build asked numpy for 24 GiB."""
    import yaml

    doc = yaml.safe_load(HEXAGON.read_text())
    for m in doc["patches"][0]["modules"]:
        m["position"] = [v * 1000.0 for v in m["position"]]
    mm = tmp_path / "mm.yaml"
    mm.write_text(yaml.safe_dump(doc))
    with pytest.raises(LayoutError, match=r"modules\[\d\]\.position.*millimetres given\?"):
        load_layout(mm)


def test_numbers_yaml_reads_as_strings_are_taken_in_lists_as_in_scalars(doc):
    """PyYAML (YAML 1.1) reads 5e-3 as a string; scalars took it, positions, a surface's
    origin and orientation and Ψ refused it ("expected [x, y] in metres, got ['5e-3', 0]")."""
    m = doc["patches"][0]["modules"][1]
    x, y = m["position"]
    m["position"] = [f"{x:e}", y]
    doc["patches"][0]["surface"] = {
        "frame_id": "l_forearm",
        "shape": "plane",
        "origin": ["5e-2", 0, "0"],
        "orientation": [0, 0, 0, "1e0"],
    }
    doc["patches"][0]["model"] = {"kind": "boussinesq", "psi": "25e-2"}
    p = parse_layout(doc).patches[0]
    assert p.modules[1].position == pytest.approx((x, y))
    assert p.surface.origin == (0.05, 0.0, 0.0) and p.surface.orientation == (0, 0, 0, 1.0)
    assert p.model.psi == 0.25
    m["position"] = ["five", y]
    with pytest.raises(LayoutError, match=r"modules\[1\]\.position: expected \[x, y\]"):
        parse_layout(doc)


def test_a_patch_spread_over_more_than_half_a_metre_is_refused(doc):
    """Two modules given in a robot frame by mistake, 1.4 m apart: the build's grid covered
    their bounding box (6 GiB); a patch is one piece of skin on one link."""
    doc["patches"][0]["modules"][5]["position"] = [1.0, 1.0]
    with pytest.raises(LayoutError, match=r"patches\[0\]\.modules: the taxels span 1\.4\d m"):
        parse_layout(doc)
