"""A bundle calibrated as a user does it: the presses written to an ``.npz`` and
``python -m tactile_contact.offline.calibrate LAYOUT PRESSES.npz -o DIR`` run in its own
process (named indenters)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from benchkit import LAYOUT, ROOT
from benchkit.protocol import Patch


def calibrated_bundle(
    lay: Patch,
    cal: dict[str, NDArray],
    delta_c: NDArray,
    folder: Path,
    tag: str,
    retry_uncertain: bool = False,
) -> tuple[Path | None, str]:
    """Calibrate on the presses ``cal`` (benchkit.truths.calibration_presses: forces,
    centres, indenters) read as ``delta_c`` (N, K) [F]; (the bundle's folder or None, the
    command's summary line or its error). ``retry_uncertain``: a fit refused as uncertain is
    run again with ``--accept-uncertain`` (the bundle it would have written)."""
    npz = folder / f"presses_{tag}.npz"
    np.savez(
        npz,
        deflection=lay.to_deflection(delta_c),
        force=cal["f"],
        position=cal["c"],
        indenter=cal["ind"],
    )
    out = folder / f"calibrated_{tag}"
    cmd = [sys.executable, "-m", "tactile_contact.offline.calibrate", str(LAYOUT), str(npz)]
    proc = subprocess.run([*cmd, "-o", str(out)], capture_output=True, text=True, cwd=ROOT)
    refused = proc.returncode != 0 and "--accept-uncertain" in proc.stderr + proc.stdout
    if retry_uncertain and refused:
        cmd.append("--accept-uncertain")
        proc = subprocess.run([*cmd, "-o", str(out)], capture_output=True, text=True, cwd=ROOT)
    if proc.returncode != 0:
        return None, (proc.stderr or proc.stdout).strip().splitlines()[-1]
    found = sorted(q.parent for q in out.rglob("manifest.json"))
    lines = [s for s in proc.stdout.splitlines() if s.strip()]
    return (found[0] if found else None), (lines[-2] if len(lines) > 1 else "")
