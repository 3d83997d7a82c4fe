"""Import before numpy: BLAS, OpenMP and numba pinned to one thread, as the node runs.

The *_NUM_THREADS variables are read when those libraries load, so this module must be
imported before numpy (``import benchkit.onecore  # noqa: F401`` sorts before it); the script
also calls ``threadpoolctl.threadpool_limits(1)`` for libraries already loaded.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_v, "1")
