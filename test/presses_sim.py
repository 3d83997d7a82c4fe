"""Calibration presses simulated on a ForwardModel: the random presses that
test_calibrate, test_calibration_identified and test_calibration_families fit.

Each draw keeps the order the three tests had, so their presses are the same bit for bit."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from tactile_contact.model.forward import ForwardModel
from tactile_contact.offline.presses import INDENTERS


def random_presses(
    xy: NDArray[np.float64],
    fm: ForwardModel,
    n: int,
    seed: int,
    *,
    gain: float = 1.0,
    near: float = 3e-3,
    noise: float = 0.01,
    per_reading: bool = False,
    named: bool = True,
) -> dict[str, NDArray]:
    """``n`` presses of the paper's indenters (chosen at random) at 0.5–3 N, each centred
    within ``near`` [m] of a taxel of ``xy`` [m], read as ``gain`` × fm's compression [m].

    Noise: Gaussian, ``noise`` × the press's largest reading for every reading (per peak), or
    ``noise`` × each reading itself (``per_reading``: a relative error on each taxel). The
    keys are those of a presses file (deflection, force, position, indenter); without
    ``named`` the indenter key is left out, as for presses whose indenters are unknown."""
    rng = np.random.default_rng(seed)
    names = list(INDENTERS)
    out: dict[str, list] = {"deflection": [], "force": [], "position": [], "indenter": []}
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    while len(out["force"]) < n:
        c = rng.uniform(lo, hi)
        if np.min(np.hypot(*(xy - c).T)) > near:
            continue
        name, f = names[rng.integers(len(names))], float(rng.uniform(0.5, 3.0))
        d = gain * fm.compression(INDENTERS[name], f, c)
        if per_reading:
            d = d * (1.0 + noise * rng.normal(size=d.shape))
        else:
            d = d + rng.normal(0, noise * np.abs(d).max(), d.shape)
        out["deflection"].append(d)
        out["force"].append(f)
        out["position"].append(c)
        out["indenter"].append(name)
    if not named:
        out.pop("indenter")
    return {k: np.array(v) for k, v in out.items()}
