"""tactile-contact-import-icub on real iCub files (test/data/icub, README there): readers,
anomalies, placement and flattening, errors and the shipped configs in config/icub."""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from tactile_contact.model.layout import load_layout, parse_layout
from tactile_contact.offline.icub.cli import main
from tactile_contact.offline.icub.errors import IcubFileError
from tactile_contact.offline.icub.importer import import_part
from tactile_contact.offline.icub.ini import read_ini
from tactile_contact.offline.icub.positions import read_positions
from tactile_contact.offline.icub.robot_xml import part_addresses, read_skin_spec
from tactile_contact.offline.icub.surface_fit import fit_cylinder, fit_surface

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "test" / "data" / "icub"
FOREARM = (DATA / "left_forearm_V2.ini", DATA / "left_forearm_V2.txt")
LEG = (DATA / "left_leg_lower.ini", DATA / "left_leg_lower.txt")
HAND = (DATA / "left_hand_V2_1.ini", DATA / "left_hand_V2_1.txt")
ARM_SPEC = DATA / "left_arm-eb24-j4_7-skinSpec.xml"


@pytest.fixture(scope="module")
def forearm():
    return import_part(*FOREARM, boards=(13, 12))


@pytest.fixture(scope="module")
def leg():
    # 380 taxels: one patch per board by default, as config/icub/left_leg_lower.yaml.
    return import_part(*LEG, boards=(8, 9, 10, 11))


# -- readers -----------------------------------------------------------------------------


def test_readers_parse_the_real_files():
    ini = read_ini(FOREARM[0])
    assert ini.cardid == (13, 12) and ini.robot_part == "left_forearm"
    assert len(ini.sensors) == 24 and {s.type for s in ini.sensors} == {"triangle_10pad"}
    assert [s.mirror for s in ini.sensors].count(True) == 16  # board 13
    pos = read_positions(FOREARM[1])
    assert pos.link == "l_forearm" and pos.rows.shape == (384, 6)
    assert int((~pos.empty).sum()) == 240  # 24 triangles × 10 taxels, pads empty
    spec = read_skin_spec(ARM_SPEC)
    assert spec.enabled_triangles(12) == {0, 1, 3, 6, 8, 9, 12, 13}
    assert spec.triangle(14, 0).shift == 0 and spec.triangle(14, 0).cdc_offset == 0x2000
    assert spec.board(14).skin_type == 1
    robot = (DATA / "left_arm-eb24-j4_7-skin.xml", DATA / "left_arm-skin_wrapper.xml")
    assert part_addresses(*robot, "left_forearm") == (13, 12)
    assert part_addresses(*robot, "left_hand") == (14,)
    leg_robot = (DATA / "left_leg-eb10-skin.xml", DATA / "left_leg-skin_wrapper.xml")
    # Two CAN patches: patch 2's boards come first in the vector ([13 12 8 9 10 11 1..7]).
    assert part_addresses(*leg_robot, "left_leg_lower") == (8, 9, 10, 11)
    assert part_addresses(*leg_robot, "left_foot") == (13, 12)


def _edit(tmp_path: Path, src: Path, fn) -> Path:
    lines = src.read_text(encoding="utf-8").splitlines()
    out = tmp_path / src.name
    out.write_text("\n".join(fn(lines)) + "\n", encoding="utf-8")
    return out


def _line_of(lines: list[str], start: str) -> int:
    return next(i for i, s in enumerate(lines) if s.startswith(start))


def _replace_line(start: str, new: str):
    def fn(lines):
        lines[_line_of(lines, start)] = new
        return lines

    return fn


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (_replace_line("triangle_10pad\t9\t", "triangle_10pad\t9\t164.66\tabc\t-150\t5\t1"),
         "Y: expected a number, got 'abc'"),
        (_replace_line("triangle_10pad\t9\t", "triangle_10pad\t9\t164.66"),
         "sensor line has 3 field(s)"),
        (_replace_line("triangle_10pad\t9\t", "triangle_10pad\t8\t164.66\t-4\t-150\t5\t1"),
         "slot 8 listed twice (also line"),
        (_replace_line("triangle_10pad\t9\t", "triangle_10pad\t9\t164.66\t-4\t-150\t5\t2"),
         "Mirror: expected 0 or 1"),
        (_replace_line("triangle_10pad\t9\t", "triangle_10pad\t300\t164.66\t-4\t-150\t5\t1"),
         "id 300 outside 0..255"),
        (lambda lines: [s for s in lines if "[SENSORS]" not in s], "no [SENSORS] group"),
    ],
)  # fmt: skip
def test_ini_errors_name_file_and_line(tmp_path, edit, message):
    bad = _edit(tmp_path, FOREARM[0], edit)
    with pytest.raises(IcubFileError) as exc:
        read_ini(bad)
    assert message in str(exc.value)
    assert str(exc.value).startswith(str(bad))


def test_a_real_ini_with_a_slot_listed_twice_is_refused():
    with pytest.raises(IcubFileError, match=r"right_arm_V2_7.ini:\d+: slot 61 listed twice"):
        read_ini(DATA / "right_arm_V2_7.ini")


def _row(k: int):
    """Edit the calibration row of port index k."""

    def wrap(new: str):
        def fn(lines):
            lines[_line_of(lines, "[calibration]") + 1 + k] = new
            return lines

        return fn

    return wrap


@pytest.mark.parametrize(
    ("edit", "message", "line"),
    [
        (_row(5)("-0.0323\t-0.0642\t0.0178\t-0.9877\t0.0707"), "has 5 field(s); expected 6", 10),
        (_row(5)("-0.0323\t-0.0642\tx0.0178\t-0.9877\t0.0707\t0.1"),
         "calibration row 5, z: expected a number, got 'x0.0178'", 10),
        (_row(5)("-32.3\t-64.2\t17.8\t-0.9877\t0.0707\t0.1393"), "files are in metres", 10),
        (_row(5)("nan\t0\t0\t0\t0\t1"), "non-finite", 10),
        (lambda lines: [s for s in lines if s != "[calibration]"], "no [calibration] group", None),
        (lambda lines: [s.replace(")", "") for s in lines], "taxel2Repr: list not closed", 3),
    ],
)  # fmt: skip
def test_positions_errors_name_file_and_line(tmp_path, edit, message, line):
    bad = _edit(tmp_path, FOREARM[1], edit)
    with pytest.raises(IcubFileError) as exc:
        read_positions(bad)
    assert message in str(exc.value)
    assert exc.value.line == line and exc.value.path == str(bad)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("<params><group name='defaultCfgBoard'>", "not well-formed XML"),
        ("<params><group name='x'><param name='a'>1</param></group></params>",
         'no <group name="defaultCfgBoard">'),
    ],
)  # fmt: skip
def test_xml_errors(tmp_path, text, message):
    f = tmp_path / "spec.xml"
    f.write_text(text)
    with pytest.raises(IcubFileError, match=message):
        read_skin_spec(f)


def test_skin_spec_rows_with_missing_fields_are_refused(tmp_path):
    bad = _edit(
        tmp_path,
        ARM_SPEC,
        lambda ls: [s.replace("14        8             11             1", "14  8") for s in ls],
    )
    with pytest.raises(IcubFileError, match=r"triangleSetCfg2: expected 7 fields") as exc:
        read_skin_spec(bad)
    assert exc.value.line is not None


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ('"noLoad">         0xf0', '"noLoad">         0x1f0',
         r"noLoad 0x1f0 = 496 outside 0\.\.255"),
        ("1              2           0x2200       </param>",
         "1              16           0x2200       </param>", r"shift 16 outside 0\.\.15"),
        ("1           14          14          50", "1           14          13          50",
         "addrEnd 13 before addrStart 14"),
    ],
)  # fmt: skip
def test_skin_spec_values_the_boards_cannot_take_name_the_spec_file_and_line(
    tmp_path, old, new, message
):
    """noLoad 0x1f0 or shift 16 reached the layout and were blamed on the .ini there."""
    bad = _edit(tmp_path, ARM_SPEC, lambda ls: [s.replace(old, new, 1) for s in ls])
    with pytest.raises(IcubFileError, match=message) as exc:
        read_skin_spec(bad)
    assert exc.value.line is not None and str(bad) in str(exc.value)


def test_robot_files_with_an_address_twice_or_a_port_twice_are_refused(tmp_path):
    skin, wrapper = DATA / "left_arm-eb24-j4_7-skin.xml", DATA / "left_arm-skin_wrapper.xml"
    text = skin.read_text()
    listed = re.search(r'"skinCanAddrsPatch1">([^<]*)<', text).group(1).split()
    dup = tmp_path / "skin.xml"
    dup.write_text(text.replace(" ".join(listed), " ".join([*listed[:-1], listed[0]]), 1))
    with pytest.raises(IcubFileError, match=rf"CAN address {int(listed[0], 0)} listed twice"):
        part_addresses(dup, wrapper, "left_forearm")
    high = tmp_path / "skin16.xml"
    high.write_text(text.replace(" ".join(listed), " ".join([*listed[:-1], "16"]), 1))
    with pytest.raises(IcubFileError, match=r"address 16 outside 0\.\.15"):
        part_addresses(high, wrapper, "left_forearm")
    lines = wrapper.read_text().splitlines()
    k = next(i for i, s in enumerate(lines) if '"left_forearm"' in s)
    twice = tmp_path / "wrapper.xml"
    twice.write_text("\n".join([*lines[: k + 1], lines[k], *lines[k + 1 :]]) + "\n")
    with pytest.raises(IcubFileError, match=r"port left_forearm defined twice \(also at line"):
        part_addresses(skin, twice, "left_forearm")


# -- files that do not match each other ----------------------------------------------------


def _drop_rows(n: int):
    def fn(lines):
        while not lines[-1].strip():
            lines.pop()
        return lines[:-n]

    return fn


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (_drop_rows(12), "372 calibration rows, expected 384 = 192 per board × 2 board(s)"),
        (lambda ls: [*ls, "0 0 0 0 0 0"], "385 calibration rows, expected 384"),
    ],
)
def test_missing_or_extra_rows(tmp_path, edit, message):
    bad = _edit(tmp_path, FOREARM[1], edit)
    with pytest.raises(IcubFileError, match=re.escape(message)) as exc:
        import_part(FOREARM[0], bad, boards=(13, 12))
    # the line of the first extra row, or of the last row when rows are missing
    n = len(bad.read_text(encoding="utf-8").rstrip("\n").splitlines())
    assert exc.value.path == str(bad) and exc.value.line == n


def test_rows_of_a_slot_the_ini_does_not_list(tmp_path):
    ini = _edit(
        tmp_path, FOREARM[0], lambda ls: [s for s in ls if not s.startswith("triangle_10pad\t9\t")]
    )
    with pytest.raises(IcubFileError) as exc:
        import_part(ini, FOREARM[1], boards=(13, 12))
    assert "hold taxels of slot(s) [9]" in str(exc.value)
    assert "the positions file does not match the .ini" in str(exc.value)
    assert exc.value.line == 4 + 1 + 12 * 9  # the first row of slot 9 (after 4 header lines)


def test_positions_of_another_part_are_refused():
    with pytest.raises(IcubFileError, match=r"does not match the \.ini"):
        import_part(FOREARM[0], LEG[1], boards=(13, 12, 1, 2))


def test_palm_positions_of_another_hand_revision_are_refused_by_the_cli(tmp_path):
    # left_hand.ini: the V1 palm, four 12-taxel triangles on slots 8..11, whose rows in the
    # V2.1 hand's file are the V2 palm's; placed from them, slots 8 and 9 overlap.
    ini = DATA / "left_hand.ini"
    proc = subprocess.run(
        [sys.executable, "-m", "tactile_contact.offline.icub.cli", str(ini), str(HAND[1]),
         "-o", str(tmp_path / "x.yaml"), "--boards", "14"],
        capture_output=True, text=True, cwd=ROOT, check=False,
    )  # fmt: skip
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"ERROR: {ini}:23: slots 8 and 9")
    assert "disagree on where these modules are" in lines[0]
    assert not (tmp_path / "x.yaml").exists()


def test_estimated_positions_too_noisy_for_one_patch_go_per_board():
    # left_arm_mesh.txt: positions estimated from taxel responses (2.4-4.2 mm rms off the
    # template), so modules are placed from each board's .ini drawing; as one patch two
    # boards' drawings collide, so auto splits per board, and --split part is refused.
    arm = (DATA / "left_arm.ini", DATA / "left_arm_mesh.txt")
    r = import_part(*arm, boards=(11, 10, 9, 8))
    assert [p.name for p in r.layout.patches] == [f"left_arm_b{a}" for a in (11, 10, 9, 8)]
    assert sum(len(p.modules) for p in r.layout.patches) == 38
    assert any("cannot be placed as one patch" in n for n in r.report.notes)
    assert sum(a.kind == "noisy_rows" for a in r.report.anomalies) >= 30
    with pytest.raises(IcubFileError, match=r"overlap once placed") as exc:
        import_part(*arm, boards=(11, 10, 9, 8), split="part")
    assert exc.value.path == str(arm[0]) and exc.value.line is not None


def test_an_ini_of_unsupported_sensors_only_names_them(tmp_path):
    ini = tmp_path / "quad.ini"
    ini.write_text("cardid 14\n[SENSORS]\nquad16 0 0 0 0 1 0\n", encoding="utf-8")
    with pytest.raises(IcubFileError, match=r"quad.ini:3: no sensor of a type .*only quad16"):
        import_part(ini, HAND[1])


def test_unknown_sensor_type_names_the_line(tmp_path):
    ini = _edit(
        tmp_path,
        FOREARM[0],
        lambda ls: [s.replace("triangle_10pad\t9\t", "triangle_11pad\t9\t") for s in ls],
    )
    with pytest.raises(
        IcubFileError, match=r"left_forearm_V2.ini:\d+: unknown sensor type 'triangle_11pad'"
    ):
        import_part(ini, FOREARM[1], boards=(13, 12))


def test_too_few_board_addresses():
    # torso.ini's cardid line names one board for four.
    with pytest.raises(ValueError, match=r"cardid lists 1 address.*give the 4 addresses"):
        import_part(DATA / "torso.ini", DATA / "torso.txt")
    with pytest.raises(ValueError, match="--boards lists 1 board address"):
        import_part(*FOREARM, boards=(13,))


# -- anomalies, absorbed and reported ------------------------------------------------------


def test_forearm_anomalies(forearm):
    rep = forearm.report
    copies = [a for a in rep.anomalies if a.kind == "centre_copies"]
    # CONVENTIONS: 92 of the 240 taxel rows are copies of their triangle's centre row.
    assert sum(len(a.rows) for a in copies) == 92
    assert all(r // 12 == a.slot and r % 12 != 3 for a in copies for r in a.rows)
    mirrored = sorted(a.slot for a in rep.anomalies if a.kind == "mirrored_pattern")
    assert mirrored == list(range(16))  # exactly board 13's triangles
    assert "constant_normals" not in rep.kinds()  # the forearm's normals are real


def test_auto_split_keeps_the_forearm_whole_and_splits_the_leg(forearm, leg):
    assert [p.name for p in forearm.layout.patches] == ["left_forearm"]
    assert [p.name for p in leg.layout.patches] == [f"left_leg_lower_b{a}" for a in (8, 9, 10, 11)]
    assert any("more than 300 for one patch" in n for n in leg.report.notes)
    whole = import_part(*LEG, boards=(8, 9, 10, 11), split="part")
    assert len(whole.layout.patches) == 1 and whole.report.patches[0].within_targets
    torso = import_part(DATA / "torso.ini", DATA / "torso.txt", boards=(7, 8, 9, 10))
    assert len(torso.layout.patches) == 4  # not one cylinder (rows 5 mm rms off the best)
    assert all(f.within_targets for f in torso.report.patches)


def test_leg_anomalies(leg):
    kinds = leg.report.kinds()
    assert {"constant_normals", "taxel2repr_length"} <= kinds
    assert "mirrored_pattern" not in kinds and "centre_copies" not in kinds


def test_stale_cardid_reordered_by_the_skin_spec_and_disabled_triangles():
    r = import_part(DATA / "left_arm_V2_7.ini", DATA / "left_arm.txt", skin_spec=ARM_SPEC)
    assert r.report.addresses == (11, 10, 9, 8)  # cardid says 8 9 10 11
    assert "stale_cardid" in r.report.kinds()
    off = sorted(a.slot for a in r.report.anomalies if a.kind == "disabled_in_spec")
    assert off == [5, 6, 53]
    assert "last_row" in r.report.kinds()  # left_arm.txt has data in its last row
    placed = {(m.board, m.triangle) for p in r.layout.patches for m in p.modules}
    assert (8, 5) not in placed and len(placed) == 32


def test_cardid_without_confirmation_is_warned(forearm):
    r = import_part(*FOREARM)
    assert r.report.addresses == (13, 12)
    assert any("WARNING" in n and "cardid" in n for n in r.report.notes)
    assert not any("WARNING" in n for n in forearm.report.notes)


def test_hand_palm_imported_fingertips_left_out_with_the_reason():
    r = import_part(*HAND, skin_spec=ARM_SPEC)
    (patch,) = r.layout.patches
    assert [m.type for m in patch.modules] == [f"icub_palm_left_{k}" for k in range(4)]
    assert [m.triangle for m in patch.modules] == [8, 9, 10, 11] and patch.surface.shape == "plane"
    assert len(r.report.skipped) == 5 and all("fingertip" in s for s in r.report.skipped)
    # The palm's channel 25 (slot 10, channel 1) is 2.8 mm off in the positions file.
    (off,) = [a for a in r.report.anomalies if a.kind == "taxel_offset"]
    assert off.rows == (121,)
    assert patch.sensor.shift == 2 and patch.sensor.cdc_offset == 0x2200


def test_right_palm_types_fit_the_right_hand_file():
    # The right palm's template is its drawing mirror-imaged (modules.py); the r_hand
    # positions file, written independently, must fit it as it is, not mirrored.
    r = import_part(DATA / "right_hand_V2_1.ini", DATA / "right_hand_V2_1.txt")
    (patch,) = r.layout.patches
    assert patch.modules[0].type == "icub_palm_right_0" and not patch.modules[0].mirrored
    (fig,) = r.report.patches
    assert fig.median < 1e-4 and fig.worst < 3e-3
    assert "mirrored_pattern" not in r.report.kinds()


# -- geometry ------------------------------------------------------------------------------


def test_cylinder_fit_recovers_a_known_cylinder():
    rng = np.random.default_rng(3)
    axis = np.array([0.2, 0.9, -0.1])
    axis /= np.linalg.norm(axis)
    e1 = np.cross(axis, [1.0, 0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    phi = rng.uniform(-1.2, 1.6, 300)
    z = rng.uniform(-0.04, 0.05, 300)
    centre = np.array([0.01, -0.02, 0.03])
    pts = centre + 0.036 * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)
    pts += z[:, None] * axis + rng.normal(0, 2e-4, (300, 3))
    fit = fit_cylinder(pts)
    assert fit.radius == pytest.approx(0.036, abs=1e-4)
    assert abs(fit.axis @ axis) == pytest.approx(1.0, abs=1e-5)
    # Unrolled, arc lengths at the fitted radius and axial distances are kept.
    uv = fit.flatten(pts[:2])
    dphi = np.angle(np.exp(1j * (phi[1] - phi[0])))
    assert abs(uv[1, 0] - uv[0, 0]) == pytest.approx(0.036 * abs(dphi), abs=2e-3 * abs(dphi) + 5e-4)
    flat = fit_surface(np.column_stack([rng.uniform(0, 0.1, (50, 2)), np.full(50, 0.0075)]))
    assert flat.shape == "plane" and flat.rms < 1e-9


def test_forearm_radius_matches_the_measured_one(forearm):
    (fig,) = forearm.report.patches
    # CONVENTIONS.md §4 (numpy fit of the same file, done independently): R = 35.9 mm.
    assert fig.radius == pytest.approx(0.0359, abs=0.0005)
    assert fig.within_targets


def _centre_rows(result, pos_path):
    """(module centre mapped to the robot, the file's centre row) per icub_v2_10pad module."""
    pos = read_positions(pos_path)
    out = []
    for p in result.layout.patches:
        for m in p.modules:
            slot = result.report.addresses.index(m.board) * 16 + m.triangle
            got = p.surface.to_link(np.array([m.position]))[0]
            out.append((got, pos.positions[12 * slot + 3]))
    return np.array(out)


@pytest.mark.parametrize("which", ["forearm", "leg"])
def test_modules_mapped_back_onto_the_robot_land_on_their_3d_centres(which, forearm, leg):
    r, path = (forearm, FOREARM[1]) if which == "forearm" else (leg, LEG[1])
    pairs = _centre_rows(r, path)
    d = np.linalg.norm(pairs[:, 0] - pairs[:, 1], axis=1)
    # The section is not round: the forearm's rows lie up to 4 mm off its cylinder.
    assert np.median(d) < 2.5e-3 and d.max() < 5e-3


def test_leg_taxels_mapped_back_match_the_cad_rows(leg):
    pos = read_positions(LEG[1])
    d = []
    for p in leg.layout.patches:
        xyz = p.surface.to_link(p.taxel_xy())
        for k, tid in enumerate(p.taxel_ids()):
            board, tri, ch = tid >> 8, (tid >> 4) & 15, tid & 15
            row = 12 * (leg.report.addresses.index(board) * 16 + tri) + ch
            d.append(np.linalg.norm(xyz[k] - pos.positions[row]))
    # Each board's rows lie 0.5-1.4 mm rms off its cylinder (the section is not round).
    assert np.median(d) < 1.5e-3 and np.percentile(d, 95) < 3.5e-3


def test_normals_come_from_the_geometry(leg):
    # The file's normals are the constant (1, 0, 0); the layout's point away from the axis.
    p = leg.layout.patches[0]
    n = p.surface.normals(p.taxel_xy())
    assert np.ptp(n, axis=0).max() > 0.3
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0)


def test_a_module_without_rows_is_placed_from_the_ini(tmp_path, leg):
    # Slot 5's rows emptied: the .ini drawing of its board places it.
    def empty_slot_5(lines):
        first = _line_of(lines, "[calibration]") + 1 + 12 * 5
        lines[first : first + 12] = ["0 0 0 0 0 0"] * 12
        return lines

    bad = _edit(tmp_path, LEG[1], empty_slot_5)
    r = import_part(LEG[0], bad, boards=(8, 9, 10, 11))
    (line,) = [m for m in r.report.modules if m.slot == 5]
    assert line.position_source == ".ini" and "no_rows" in r.report.kinds()
    ref = {(m.board, m.triangle): m for p in leg.layout.patches for m in p.modules}
    got = {(m.board, m.triangle): m for p in r.layout.patches for m in p.modules}
    # Compared on the robot (both layouts' surfaces), against the CAD file's placement.
    pa = next(p for p in r.layout.patches if got[(8, 5)] in p.modules)
    pb = next(p for p in leg.layout.patches if ref[(8, 5)] in p.modules)
    a = pa.surface.to_link(np.array([got[(8, 5)].position]))[0]
    b = pb.surface.to_link(np.array([ref[(8, 5)].position]))[0]
    assert np.linalg.norm(a - b) < 4e-3


def test_a_module_moved_in_the_file_is_an_outlier(tmp_path, leg):
    pos = read_positions(LEG[1])
    head = _line_of(LEG[1].read_text().splitlines(), "[calibration]")
    moved = pos.rows.copy()
    moved[12 * 4 : 12 * 5, 2] += 0.02  # slot 4 lifted 20 mm along z

    def fn(lines):
        for k in range(12 * 4, 12 * 5):
            if not pos.empty[k]:
                lines[head + 1 + k] = " ".join(f"{v:.6f}" for v in moved[k])
        return lines

    r = import_part(LEG[0], _edit(tmp_path, LEG[1], fn), boards=(8, 9, 10, 11), split="board")
    assert 4 in [a.slot for a in r.report.anomalies if a.kind == "outlier_module"]
    (line,) = [m for m in r.report.modules if m.slot == 4]
    assert line.position_source == ".ini"


# -- the command -----------------------------------------------------------------------------


def test_cli_writes_a_layout_that_loads(tmp_path, capsys):
    out = tmp_path / "forearm.yaml"
    assert main([*map(str, FOREARM), "-o", str(out), "--boards", "13,12"]) == 0
    text = capsys.readouterr().out
    assert "cylinder R = 35.9 mm" in text and "within targets" in text
    assert "position 3-D, rotation 3-D" in text and "[mirrored_pattern]" in text
    lay = load_layout(out)
    assert lay.patches[0].surface.frame_id == "l_forearm"
    assert len(lay.patches[0].taxel_xy()) == 240
    assert main([*map(str, FOREARM), "-o", str(out)]) == 1  # never overwrites...
    assert "exists; pass --force" in capsys.readouterr().err
    assert main([*map(str, FOREARM), "-o", str(out), "--force", "--quiet"]) == 0  # ...unless told
    assert "WARNING" in capsys.readouterr().out  # the cardid warning survives --quiet


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--boards", "13,x"], "expected comma-separated CAN addresses"),
        (["--boards", "13,16"], "CAN addresses are 0..15"),
        (["--split", "thirds"], "invalid choice: 'thirds'"),
    ],
)
def test_cli_bad_arguments(tmp_path, capsys, args, message):
    with pytest.raises(SystemExit) as exc:
        main([*map(str, FOREARM), "-o", str(tmp_path / "x.yaml"), *args])
    assert exc.value.code == 2 and message in capsys.readouterr().err


def test_cli_refuses_half_the_robot_files(tmp_path, capsys):
    wrapper = str(DATA / "left_arm-skin_wrapper.xml")
    assert main([*map(str, FOREARM), "-o", str(tmp_path / "x.yaml"), "--wrapper", wrapper]) == 1
    assert "give both the robot's skin.xml" in capsys.readouterr().err


def test_cli_bad_file_is_one_error_line_without_traceback(tmp_path):
    bad = _edit(tmp_path, FOREARM[1], _row(7)("0.1 0.2 nope 0 0 1"))
    proc = subprocess.run(
        [sys.executable, "-m", "tactile_contact.offline.icub.cli", str(FOREARM[0]), str(bad),
         "-o", str(tmp_path / "x.yaml")],
        capture_output=True, text=True, cwd=ROOT, check=False,
    )  # fmt: skip
    assert proc.returncode == 1
    assert proc.stderr.strip() == (
        f"ERROR: {bad}:12: calibration row 7, z: expected a number, got 'nope'"
    )
    assert "Traceback" not in proc.stderr and not (tmp_path / "x.yaml").exists()


# -- shipped configs -------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["left_forearm_V2", "left_leg_lower", "left_hand_V2_1"])
def test_shipped_configs_are_what_the_importer_writes(name, monkeypatch, tmp_path, capsys):
    shipped = ROOT / "config" / "icub" / f"{name}.yaml"
    text = shipped.read_text(encoding="utf-8")
    command = next(s for s in text.splitlines() if s.startswith("# command: "))
    args = shlex.split(command.removeprefix("# command: "))[1:]
    out = args.index("-o")
    args[out + 1] = str(tmp_path / "again.yaml")
    monkeypatch.chdir(ROOT)  # the sources are named relative to the repository
    assert main(args) == 0
    again = (tmp_path / "again.yaml").read_text(encoding="utf-8")
    strip = lambda t: [s for s in t.splitlines() if not s.startswith("# command: ")]  # noqa: E731
    assert strip(again) == strip(text)
    for p in load_layout(shipped).patches:
        assert p.surface is not None
    figures = yaml.safe_load(text)  # the layout itself is checked by load_layout above
    assert figures["patches"]
    capsys.readouterr()


@pytest.mark.parametrize("name", ["left_forearm_V2", "left_leg_lower", "left_hand_V2_1"])
def test_shipped_parts_meet_the_flattening_targets(name):
    text = (ROOT / "config" / "icub" / f"{name}.yaml").read_text(encoding="utf-8")
    args = shlex.split(next(s for s in text.splitlines() if s.startswith("# command: "))[11:])
    r = import_part(
        ROOT / args[1], ROOT / args[2], boards=None,
        skin_spec=ROOT / args[args.index("--skin-spec") + 1],
        robot_skin=ROOT / args[args.index("--robot-skin") + 1],
        wrapper=ROOT / args[args.index("--wrapper") + 1],
        split=args[args.index("--split") + 1] if "--split" in args else "auto",
    )  # fmt: skip
    for f in r.report.patches:
        assert f.median <= 1.5e-3 and f.p95 <= 4e-3, f


def test_bus_names_the_patches_can_bus(tmp_path, capsys):
    r = import_part(*HAND, bus="left_arm_can1")
    assert [p.bus for p in r.layout.patches] == ["left_arm_can1"]
    out = tmp_path / "hand.yaml"
    assert main([*map(str, HAND), "-o", str(out), "--bus", "left arm"]) == 1
    assert "bus: expected a name of letters, digits" in capsys.readouterr().err
    assert not out.exists()


def test_a_mistyped_row_is_left_out_and_reported_not_a_board_mirrored(tmp_path, leg):
    """One digit shifted in a row of the leg's positions (x 0.048636 → 0.48636: 0.44 m off,
    still under the file's 2 m bound) turned its board's cylinder R 52 → 216 mm and all ten
    of its modules 'mirrored'. The row lies far from its module's other rows: left out,
    reported with its line, and the board placed as from the real file."""
    bad = _edit(tmp_path, LEG[1], lambda ls: [s.replace("0.048636", "0.48636", 1) for s in ls])
    got = import_part(LEG[0], bad, boards=(8, 9, 10, 11))
    outliers = [a for a in got.report.anomalies if a.kind == "outlier_rows"]
    assert len(outliers) == 1 and "line 6" in outliers[0].message, outliers
    assert "mirrored_pattern" not in got.report.kinds()
    radius = {p.name: p.fit.radius for p in got.patches}
    for p in leg.patches:
        assert radius[p.name] == pytest.approx(p.fit.radius, rel=0.1), (p.name, radius)


@pytest.mark.parametrize(
    ("name", "bus", "expect_name"),
    [("yes", "1", "yes"), ("left-arm", "can-0", "left_arm"), ("12", "", "skin_12")],
)
def test_names_and_buses_are_written_as_the_strings_they_are(name, bus, expect_name):
    """`--bus 1` wrote `bus: 1` (an int when read back: an AssertionError traceback), `--name
    yes` a bool, `--name left-arm` a patch whose ROS topics rclpy refuses: names become ROS
    tokens, and both are quoted where YAML would read them as something else."""
    r = import_part(*FOREARM, boards=(13, 12), name=name, bus=bus)
    (p,) = r.layout.patches
    assert (p.name, p.bus) == (expect_name, bus)
    (again,) = parse_layout(yaml.safe_load(r.text)).patches
    assert (again.name, again.bus) == (expect_name, bus)
