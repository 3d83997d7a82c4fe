"""The offline tool as users run it: a subprocess."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import yaml

from tactile_contact.bundle import load_bundle
from tactile_contact.layout import load_layout

ROOT = Path(__file__).resolve().parents[1]


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "tactile_contact.build", *args],
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
