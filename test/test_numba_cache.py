"""numba's disk cache and the package's compiled kernels.

numba invalidates a cached kernel when its own source file changes, not when a kernel it calls
from another file does: a kernel calling another module's kernel keeps a stale copy of it
compiled in after that module changes (seen: FrameFusion's Jacobian kept an old
``_round_kernels.predict`` and every bundle was refused with "NRT_adapt_ndarray_to_python:
descr is NULL"). So a cached kernel calls only kernels of its own file."""

from __future__ import annotations

import importlib
import inspect
import os
import subprocess
import sys
import textwrap
from pathlib import Path

from numba.core.registry import CPUDispatcher

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "tactile_contact"


def _kernel_modules() -> list[str]:
    names = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if "cache=True" in path.read_text(encoding="utf-8") or "_JIT" in path.read_text(
            encoding="utf-8"
        ):
            rel = path.relative_to(ROOT).with_suffix("")
            names.append(".".join(rel.parts))
    return names


def test_no_cached_kernel_calls_a_kernel_of_another_file() -> None:
    crossing = []
    modules = _kernel_modules()
    assert "tactile_contact.inverse._round_kernels" in modules
    for name in modules:
        mod = importlib.import_module(name)
        here = inspect.getsourcefile(mod)
        kernels = {k: v for k, v in vars(mod).items() if isinstance(v, CPUDispatcher)}
        for kname, kern in kernels.items():
            if inspect.getsourcefile(kern.py_func) != here:
                continue  # a re-export: checked in its own module
            for callee in kern.py_func.__code__.co_names:
                target = vars(mod).get(callee)
                if isinstance(target, CPUDispatcher) and (
                    inspect.getsourcefile(target.py_func) != here
                ):
                    crossing.append(f"{name}.{kname} calls {target.py_func.__module__}.{callee}")
    assert not crossing, crossing


def test_a_changed_kernel_file_is_recompiled_with_its_callers(
    tmp_path: Path, hexagon_bundle: tuple[Path, object]
) -> None:
    """A copy of the package, its kernels cached by a fused reconstruction's warm-up; then
    ``_round_kernels.predict`` changes (its results scaled by 2) and a new process must see the
    change in FrameFusion's Jacobian, which calls it: a stale cached caller would not."""
    import shutil

    copy = tmp_path / "pkg"
    shutil.copytree(PACKAGE, copy / "tactile_contact", ignore=shutil.ignore_patterns("__pycache__"))
    script = textwrap.dedent(
        """
        import os, sys
        import numpy as np
        import tactile_contact
        assert tactile_contact.__file__.startswith(os.getcwd()), tactile_contact.__file__
        from tactile_contact.inverse.reconstruction import Reconstructor
        from tactile_contact.inverse.round_contact import FAMILIES, RoundFit
        from tactile_contact.inverse.summary import Contact
        from tactile_contact.inverse.temporal import round_jacobian
        r = Reconstructor.from_bundle(sys.argv[1], fuse=True)
        r.warm_up()
        x, y = (float(v) for v in r.taxel_xy[30])
        jac = round_jacobian(r._round, r.taxel_xy, (Contact(1.2, (x, y), 2e-3, "hertz"),))
        fit = RoundFit(1.2, (x, y), FAMILIES.index("hertz"), 2e-3, 0.0)
        pred = r._round.predict(fit, r.taxel_xy)
        print(float(np.abs(jac[:, 0]).sum()), float(np.abs(pred).sum()))
        """
    )

    def run() -> tuple[float, float]:
        out = subprocess.run(
            [sys.executable, "-c", script, str(hexagon_bundle[0])],
            cwd=copy,
            env={**os.environ, "PYTHONPATH": str(copy), "NUMBA_CACHE_DIR": ""},
            capture_output=True,
            text=True,
        )
        assert out.returncode == 0, out.stderr
        a, b = out.stdout.split()
        return float(a), float(b)

    jac0, pred0 = run()
    src = copy / "tactile_contact" / "inverse" / "_round_kernels.py"
    text = src.read_text(encoding="utf-8")
    head, sep, body = text.partition("\ndef predict(")
    assert sep, "predict not found"
    ret = body.index("    return out\n")
    src.write_text(head + sep + body[:ret] + "    out *= 2.0\n" + body[ret:], encoding="utf-8")
    jac1, pred1 = run()
    assert pred1 == 2 * pred0 and pred0 > 0
    assert jac1 == 2 * jac0, (jac0, jac1)
