"""Helpers shared by the bench scripts (not part of the package; ``bench/`` is on ``sys.path``
when a script runs as ``python bench/<script>.py``). One module per concern:

- :mod:`benchkit.onecore`: import it first: BLAS, OpenMP and numba pinned to one thread;
- :mod:`benchkit.protocol`: the paper's protocol (indenters, forces, places), the default
  patch and its variants, the default bundle;
- :mod:`benchkit.truths`: the independent truths (fine forward models, other taxel responses,
  presses cached under out/bench-robust-cache, Jacobians for the Cramér–Rao bound);
- :mod:`benchkit.readings`: readings and noise tiers (float, 8-bit, idle skins), seeds;
- :mod:`benchkit.stats`: error statistics, the Cramér–Rao bound, detection rates;
- :mod:`benchkit.tables`: table rows, Markdown tables, report files;
- :mod:`benchkit.timing`: wall and CPU time of calls, best-of and paired timings;
- :mod:`benchkit.configs`: library configurations under test (layout overrides, the paper's
  interpolated grid, one-pass NNLS, float64 products) as one online path each;
- :mod:`benchkit.layer`: the reference elastic layer and its square problems;
- :mod:`benchkit.skins`: multi-patch layouts and precomputed CAN frames for the ROS benches.

SI units throughout (m, Pa, N, F) unless a name says otherwise.
"""

from __future__ import annotations

import sys
from pathlib import Path

#: The repository (the package is imported from it, installed or not).
ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

#: The default patch's layout file.
LAYOUT = ROOT / "config" / "hexagon_patch.yaml"
