"""Every console script of setup.py answers ``--help`` with its usage (argparse formats the
help with %: a bare % in a help text crashed ``tactile-contact-calibrate --help``)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = re.findall(r'"([\w-]+) = ([\w.]+):(\w+)"', (ROOT / "setup.py").read_text())


def test_setup_names_the_console_scripts() -> None:
    assert {name for name, _, _ in SCRIPTS} >= {
        "tactile-contact-build",
        "tactile-contact-calibrate",
        "tactile-contact-presses",
        "tactile-contact-import-icub",
    }


@pytest.mark.parametrize(("name", "module", "func"), SCRIPTS, ids=[s[0] for s in SCRIPTS])
def test_help(name: str, module: str, func: str) -> None:
    code = f"import sys; from {module} import {func} as m; sys.argv = [{name!r}, '--help']; m()"
    run = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT
    )
    assert run.returncode == 0, run.stderr[-2000:]
    assert "usage:" in run.stdout and "Traceback" not in run.stderr
