"""The offline tool as users run it: a subprocess."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import yaml

from tactile_contact.model.layout import load_layout
from tactile_contact.offline.bundle import load_bundle

ROOT = Path(__file__).resolve().parents[1]


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "tactile_contact.offline.build", *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_builds_then_skips(tmp_path):
    layout = ROOT / "config" / "hexagon_patch.yaml"
    t = time.perf_counter()
    r = run(str(layout), "-o", str(tmp_path), "--quiet")
    assert r.returncode == 0, r.stderr
    assert time.perf_counter() - t < 30  # the issue: well under a minute
    assert "hexagon: built" in r.stdout
    load_bundle(tmp_path / "hexagon", load_layout(layout).patches[0])
    stamp = (tmp_path / "hexagon" / "manifest.json").stat().st_mtime_ns
    r = run(str(layout), "-o", str(tmp_path))
    assert r.returncode == 0 and "hexagon: up-to-date" in r.stdout
    assert (tmp_path / "hexagon" / "manifest.json").stat().st_mtime_ns == stamp
    r = run(str(layout), "-o", str(tmp_path), "--force", "--quiet")
    assert "hexagon: built" in r.stdout


def test_multi_patch_layout_in_parallel_and_rebuild_when_stale(tmp_path):
    layout = ROOT / "config" / "robot_skin.yaml"
    r = run(str(layout), "-o", str(tmp_path / "b"), "--jobs", "2", "--quiet")
    assert r.returncode == 0, r.stderr
    names = [p.name for p in load_layout(layout).patches]
    assert sorted(p.name for p in (tmp_path / "b").iterdir()) == sorted(names)
    doc = yaml.safe_load(layout.read_text())
    doc["patches"][1]["elastomer"]["young"] = 1.77e5
    edited = tmp_path / "edited.yaml"
    edited.write_text(yaml.safe_dump(doc))
    r = run(str(edited), "-o", str(tmp_path / "b"), "--quiet")
    assert f"{names[0]}: up-to-date" in r.stdout and f"{names[1]}: built" in r.stdout


def test_bad_yaml_is_an_error(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(
        "patches:\n  - name: x\n    modules: [{type: foo, board: 0, triangle: 0, "
        "position: [0, 0]}]\n"
    )
    r = run(str(bad), "-o", str(tmp_path / "out"))
    assert r.returncode == 1
    assert r.stderr.startswith(f"ERROR: {bad}: patches[0].modules[0].type: unknown module type")
    assert not (tmp_path / "out").exists()
    r = run(str(tmp_path / "missing.yaml"), "-o", str(tmp_path / "out"))
    assert r.returncode == 1 and r.stderr.startswith("ERROR: ") and "cannot read" in r.stderr
    r = run(str(ROOT / "config" / "hexagon_patch.yaml"), "-o", str(tmp_path), "--patch", "nope")
    assert r.returncode == 1 and "no patch named 'nope'" in r.stderr


def test_a_bundle_whose_layout_file_changed_is_refused_without_being_told_the_layout(tmp_path):
    """The node loads bundles by path alone: the layout file recorded at build time tells a
    module moved (or a parameter changed) since, and the stale bundle is refused."""
    import pytest

    from tactile_contact import Reconstructor
    from tactile_contact.offline.bundle import BundleStaleError

    doc = yaml.safe_load((ROOT / "config" / "robot_skin.yaml").read_text())
    layout = tmp_path / "robot.yaml"
    layout.write_text(yaml.safe_dump(doc))
    assert run(str(layout), "-o", str(tmp_path / "b"), "--quiet").returncode == 0
    first, second = (p["name"] for p in doc["patches"])
    Reconstructor.from_bundle(tmp_path / "b" / first)
    # Move one module of the second patch by a taxel pitch: only that bundle is stale.
    x, y = doc["patches"][1]["modules"][0]["position"]
    doc["patches"][1]["modules"][0]["position"] = [x + 0.0055, y]
    layout.write_text(yaml.safe_dump(doc))
    Reconstructor.from_bundle(tmp_path / "b" / first)
    with pytest.raises(BundleStaleError, match=f"layout hash differs; built from {layout}"):
        Reconstructor.from_bundle(tmp_path / "b" / second)
    # A layout file that no longer loads: refused with its error; gone: not checked.
    layout.write_text("patches: [")
    with pytest.raises(BundleStaleError, match="layout file no longer loads"):
        Reconstructor.from_bundle(tmp_path / "b" / first)
    layout.unlink()
    Reconstructor.from_bundle(tmp_path / "b" / second)


def test_tikhonov_and_tsvd_parameters_by_a_rule(tmp_path):
    """``tikhonov: discrepancy`` and ``tsvd_rank: discrepancy`` are chosen at build time on the
    representative reading; checked by the principle's definition: the residual of the chosen
    solution on that reading is the noise level σ·√K (Tikhonov), and the smallest rank whose
    residual is at most that (TSVD)."""
    import copy

    import numpy as np
    import pytest

    from tactile_contact.model.layout import LayoutError, parse_layout
    from tactile_contact.offline.build import build_patch, representative_reading

    doc = yaml.safe_load((ROOT / "config" / "hexagon_patch.yaml").read_text())
    doc["patches"][0]["solver"].update(method="tikhonov", tikhonov="discrepancy", refine="none")
    patch = parse_layout(doc).patches[0]
    manifest, arrays = build_patch(patch)
    p, c = manifest["params"], arrays["forward"]
    assert p["tikhonov_rule"] == "discrepancy" and 0 < p["tikhonov_relative"] < 10
    d = representative_reading(patch, c)
    target = patch.solver.noise * np.sqrt(len(d))
    x = arrays["inverse"].astype(np.float64) @ d
    assert np.linalg.norm(c @ x - d) == pytest.approx(target, rel=1e-3)

    tsvd = copy.deepcopy(doc)
    tsvd["patches"][0]["solver"].update(method="tsvd", tikhonov=0.1, tsvd_rank="discrepancy")
    patch = parse_layout(tsvd).patches[0]
    manifest, arrays = build_patch(patch)
    k = manifest["params"]["tsvd_rank"]
    u, s, vt = np.linalg.svd(c, full_matrices=False)

    def residual(rank):
        x = vt[:rank].T @ ((u[:, :rank].T @ d) / s[:rank])
        return np.linalg.norm(c @ x - d)

    assert 1 < k < len(d) and residual(k) <= target < residual(k - 1)
    assert manifest["params"]["tsvd_rule"] == "discrepancy"
    bad = copy.deepcopy(doc)
    bad["patches"][0]["solver"]["tikhonov"] = "magic"
    with pytest.raises(LayoutError, match=r"solver\.tikhonov: unknown rule 'magic'"):
        parse_layout(bad)


def test_a_script_without_a_main_guard_builds_a_layout_of_two_patches(tmp_path):
    """From Python, build_layout builds in the calling process unless asked for jobs: a pool's
    forkserver imports the calling script again, which an unguarded script (a user's first
    try) cannot survive. The command keeps its 2 processes (the test above)."""
    doc = yaml.safe_load((ROOT / "config" / "hexagon_patch.yaml").read_text())
    second = yaml.safe_load(yaml.safe_dump(doc["patches"][0]))
    second["name"], second["frame_id"] = "hexagon_b", "skin_hexagon_b"
    for m in second["modules"]:
        m["board"] = int(m["board"]) + 1
    doc["patches"].append(second)
    layout = tmp_path / "two.yaml"
    layout.write_text(yaml.safe_dump(doc))
    script = tmp_path / "unguarded.py"
    script.write_text(
        "from tactile_contact.offline.build import build_layout\n"
        f"print(sorted(build_layout({str(layout)!r}, {str(tmp_path / 'b')!r}).items()))\n"
    )
    r = subprocess.run(
        [sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True, timeout=120
    )
    assert r.returncode == 0, r.stderr
    assert r.stdout.count("'built'") == 2, r.stdout
    assert "[('hexagon', 'built'), ('hexagon_b', 'built')]" in r.stdout


def test_a_grid_too_large_for_memory_is_refused_before_the_build(tmp_path):
    """Modules 0.42 m apart with no grid mask asked numpy for hundreds of GiB minutes into the
    build (a MemoryError traceback, or a swapping machine): refused at once, naming the patch,
    the matrix, its size and what to change."""
    layout = tmp_path / "wide.yaml"
    layout.write_text(
        "patches:\n"
        "  - name: wide\n"
        "    modules:\n"
        "      - {type: roboskin12, board: 0, triangle: 0, position: [0.0, 0.0]}\n"
        "      - {type: roboskin12, board: 0, triangle: 1, position: [0.3, 0.3]}\n"
        "    grid: {mask: none, traction_cell: 0.0005, deflection_cell: 0.0005}\n"
    )
    r = run(str(layout), "-o", str(tmp_path / "b"), "--quiet")
    assert r.returncode == 1
    assert "ERROR: patch wide: its deflection operator would take" in r.stderr
    assert "GiB" in r.stderr and "coarser grid cells" in r.stderr
    assert not (tmp_path / "b" / "wide").exists()
