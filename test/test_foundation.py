"""The package's build plumbing: incremental setup, layout, lint configuration."""

from __future__ import annotations

import shutil
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.skipif(shutil.which("make") is None, reason="make is not installed")
@pytest.mark.skipif(
    not (ROOT / ".venv" / ".stamps" / "msgs").exists(),
    reason="not set up by `make setup` (plain pip install)",
)
def test_second_setup_builds_nothing() -> None:
    # `make -q` exits 0 only when every target is up to date, i.e. nothing would be rebuilt.
    result = subprocess.run(["make", "-q", "setup"], cwd=ROOT, capture_output=True, text=True)
    assert result.returncode == 0, "make setup would rebuild something on a second run"


def test_package_xml_is_format_3_and_names_the_package() -> None:
    root = ET.parse(ROOT / "package.xml").getroot()
    assert root.get("format") == "3"
    assert root.findtext("name") == "tactile_contact"
    assert root.findtext("export/build_type") == "ament_cmake"


def test_every_message_is_built_by_cmake() -> None:
    cmake = (ROOT / "CMakeLists.txt").read_text()
    for msg in sorted((ROOT / "msg").glob("*.msg")):
        assert f'"msg/{msg.name}"' in cmake, f"{msg.name} missing from rosidl_generate_interfaces"


def test_ros_wheels_are_pinned() -> None:
    for line in (ROOT / "requirements" / "ros.txt").read_text().splitlines():
        line = line.split("#")[0].strip()
        if line:
            assert "==" in line, f"unpinned requirement: {line}"


def test_ci_runs_the_readme_test_command() -> None:
    assert "make test" in (ROOT / ".ci" / "run").read_text()
    readme = (ROOT / "README.md").read_text()
    assert "make demo" in readme and "make test" in readme


def test_the_core_library_imports_no_ros() -> None:
    """Every module outside tactile_contact.ros (and the generated msg package) imports
    without loading rclpy or a ROS message package: the core runs and tests without ROS.
    A fresh interpreter, so that other tests' imports do not hide one."""
    import sys

    pkg = ROOT / "tactile_contact"
    names = (".".join(p.relative_to(pkg).with_suffix("").parts) for p in pkg.rglob("*.py"))
    core = sorted(
        n.removesuffix(".__init__")
        for n in names
        if n != "__init__" and n.split(".")[0] not in ("ros", "msg")
    )
    assert {"inverse.reconstruction", "canbus.codec", "model.elastic", "offline.build"} <= set(core)
    code = (
        "import importlib, sys\n"
        f"for m in {core!r}:\n"
        "    importlib.import_module('tactile_contact.' + m)\n"
        "ros = sorted(m for m in sys.modules if m.split('.')[0] == 'rclpy'"
        " or m.split('.')[0].endswith('_msgs') or m == 'tactile_contact.msg')\n"
        "print(ros)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]", out.stdout
