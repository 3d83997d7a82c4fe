"""Reconstructor.warm_up builds every compiled kernel the solve paths use, so a node's first
contact does not wait seconds for numba to compile (on a clean clone the cache is empty)."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]

# In a fresh interpreter: the kernels' compiled signatures are process-wide, and earlier tests
# in this one would have built them already.
SCRIPT = textwrap.dedent(
    """
    import json, sys
    import numba
    import numpy as np
    from tactile_contact.inverse import _round_kernels
    from tactile_contact.model.forward import ForwardModel
    from tactile_contact.model.indenters import FlatPunch, HertzSphere
    from tactile_contact.inverse.reconstruction import Reconstructor
    from tactile_contact.model.sensor import value_count_farad

    def signatures():
        return {
            name: sorted(map(str, f.signatures))
            for name, f in vars(_round_kernels).items()
            if isinstance(f, numba.core.registry.CPUDispatcher)
        }

    recon = Reconstructor.from_bundle(sys.argv[1])
    recon.warm_up()
    warmed = signatures()

    # Presses from the independent fine forward model, as a user's frames come.
    p = recon.params
    xy = recon.taxel_xy
    truth = ForwardModel(
        xy, p["thickness"], p["young"], p["poisson"], fine_cell=5e-4,
        taxel_radius=p["taxel_radius"],
    )
    lsb = value_count_farad(p["farad_per_count"], p["shift"])
    rng = np.random.default_rng(3)
    spots = [xy[30], (xy[30] + xy[31]) / 2, xy[5]]
    some = np.ones(len(xy), dtype=bool)
    some[31] = False
    for ind in (HertzSphere(6e-3), HertzSphere(3e-3), FlatPunch(6e-3), FlatPunch(1.5e-3)):
        for force in (0.3, 2.0):
            dcs = [truth.delta_c(ind, force, c, p["epsilon_r"]) for c in spots]
            for dc in (dcs[0], dcs[1], dcs[0] + dcs[2]):
                delta = recon.compression(dc)
                noisy = delta * (1 + 0.01 * rng.standard_normal(delta.shape))
                counts = np.rint(dc / lsb + 0.15 * rng.standard_normal(dc.shape)) * lsb
                recon.solve_deflection(noisy)
                recon.solve_deflection(noisy, some)
                recon.solve_deflection(noisy, noise=recon.default_noise)
                recon.solve(counts)
                recon.solve(counts, some)
    print(json.dumps({"warmed": warmed, "after": signatures()}))
    """
)


def test_warm_up_compiles_what_the_frames_need(tmp_path: Path) -> None:
    from tactile_contact.offline.build import build_layout

    build_layout(ROOT / "config" / "hexagon_patch.yaml", tmp_path)
    out = subprocess.run(
        [sys.executable, "-c", SCRIPT, str(tmp_path / "hexagon")],
        capture_output=True,
        text=True,
        timeout=600,
        check=True,
    )
    result = json.loads(out.stdout.strip().splitlines()[-1])
    warmed, after = result["warmed"], result["after"]
    # Kernels only ever inlined into others show no signature of their own; every one that
    # is called from Python must be built.
    assert all(warmed[name] for name in ("fit_near", "posterior_mean", "predict", "render")), warmed
    new = {name: sorted(set(after[name]) - set(warmed[name])) for name in after}
    assert not any(new.values()), f"compiled only on real frames, after warm_up: {new}"
