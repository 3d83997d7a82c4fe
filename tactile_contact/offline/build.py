"""Offline matrix tool: patch layout YAML → one matrix bundle per patch.

Usage::

    tactile-contact-build LAYOUT.yaml -o DIR [--force] [--jobs N] [--patch NAME ...]
    python -m tactile_contact.offline.build LAYOUT.yaml -o DIR

Each patch's bundle goes to ``DIR/<patch name>``. A bundle whose layout and parameter hashes
match the layout is skipped unless ``--force``. Patches build in parallel processes. Errors are
printed as ``ERROR: ...`` and the exit status is 1.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import multiprocessing
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tactile_contact import __version__
from tactile_contact.model.grids import Grid, disc_quadrature, skin_grid
from tactile_contact.model.layout import LayoutError, PatchLayout, load_layout
from tactile_contact.offline.bundle import BundleError, bundle_check, replacing, save_bundle

#: Disc quadrature of the taxel average (radii × angles). The electrode edge cuts through cells,
#: so convergence is slow: against 12 × 32 points the largest entry error is 6 % with 3 × 8,
#: 1 % with 6 × 16 and 0.6 % with 8 × 24 (2 mm electrode, 2 mm cells; 0.3 s for 72 taxels).
TAXEL_QUADRATURE = (8, 24)


def grids_for(patch: PatchLayout) -> tuple[Grid, Grid]:
    """(traction grid, deflection grid) of a patch, masked to its skin."""
    g = patch.grid
    xy = patch.taxel_xy()
    outlines = patch.module_outlines()
    tg = skin_grid(xy, g.traction_cell, g.margin, g.mask, g.mask_distance, outlines)
    dg = skin_grid(xy, g.deflection_cell, g.margin, g.mask, g.mask_distance, outlines)
    return tg, dg


#: Largest matrix a build makes [bytes] (float64): beyond it the layout asks for more than a
#: workstation has, and numpy would fail (or the machine swap) minutes into the build.
MAX_MATRIX_BYTES = 4 << 30


def check_size(patch: PatchLayout, tg: Grid, dg: Grid) -> None:
    """ValueError naming the patch when its largest matrix would exceed MAX_MATRIX_BYTES:
    the forward matrix (taxels × traction cells), the deflection operator (deflection cells
    × traction cells) and a Laplacian regulariser (traction cells²)."""
    k, nt, nd = len(patch.taxel_xy()), tg.n_cells, dg.n_cells
    sizes = {"forward matrix": k * nt, "deflection operator": nd * nt}
    if patch.solver.regulariser == "laplacian":
        sizes["Laplacian regulariser"] = nt * nt
    what, n = max(sizes.items(), key=lambda kv: kv[1])
    if 8 * n > MAX_MATRIX_BYTES:
        g = patch.grid
        raise ValueError(
            f"patch {patch.name}: its {what} would take {8 * n / 2**30:.1f} GiB ({nt} traction "
            f"cells of {g.traction_cell * 1e3:g} mm, {nd} deflection cells of "
            f"{g.deflection_cell * 1e3:g} mm, mask {g.mask}; at most "
            f"{MAX_MATRIX_BYTES / 2**30:g} GiB): coarser grid cells, grid.mask taxels or "
            "modules, or check the module positions"
        )


def laplacian(grid: Grid) -> NDArray[np.float64]:
    """(N, N) graph Laplacian of the masked cells (4-neighbours), the smoothness regulariser."""
    idx = -np.ones(grid.shape, dtype=int)
    idx[grid.mask] = np.arange(grid.n_cells)
    lap = np.zeros((grid.n_cells, grid.n_cells))
    for di, dj in ((0, 1), (1, 0)):
        a = idx[: grid.shape[0] - di, : grid.shape[1] - dj]
        b = idx[di:, dj:]
        ok = (a >= 0) & (b >= 0)
        i, j = a[ok], b[ok]
        np.add.at(lap, (i, i), 1.0)
        np.add.at(lap, (j, j), 1.0)
        np.add.at(lap, (i, j), -1.0)
        np.add.at(lap, (j, i), -1.0)
    return lap


def forward_matrix(patch: PatchLayout, points: NDArray, grid: Grid) -> NDArray[np.float64]:
    """(len(points), N) effective deflection per unit cell pressure [m/Pa] for the patch model."""
    from tactile_contact.model.elastic import boussinesq_matrix, love_matrix

    e, h = patch.elastomer, patch.layer_thickness
    if patch.model.kind == "love":
        return love_matrix(points, grid.centers(), grid.half_sizes(), h, e.young, e.poisson)
    per_force = boussinesq_matrix(
        points, grid.centers(), grid.cell_area, h, e.young, e.poisson, patch.model.psi
    )
    return per_force * grid.cell_area  # a cell's force is p·A


#: Taxels computed at once in :func:`taxel_matrix`: bounds the (taxels × quadrature points ×
#: cells) block in memory (a 240-taxel iCub forearm at once: 820 MB) and paces the progress.
TAXEL_CHUNK = 16


def taxel_matrix(
    patch: PatchLayout, grid: Grid, step: Callable[[int], None] | None = None
) -> NDArray[np.float64]:
    """(K, N) forward matrix C [m/Pa] from cell pressures to taxel readings: the mean over each
    taxel's footprint disc, times the taxel gain (:attr:`PatchLayout.footprint`). ``step(n)``
    is called after each TAXEL_CHUNK taxels (n of them)."""
    xy = patch.taxel_xy()
    if patch.footprint == 0:
        c = patch.model.gain * forward_matrix(patch, xy, grid)
        if step is not None:
            step(len(xy))
        return c
    q, w = disc_quadrature(patch.footprint, *TAXEL_QUADRATURE)
    out = np.empty((len(xy), grid.n_cells))
    for k0 in range(0, len(xy), TAXEL_CHUNK):
        part = xy[k0 : k0 + TAXEL_CHUNK]
        pts = (part[:, None, :] + q[None, :, :]).reshape(-1, 2)
        c = forward_matrix(patch, pts, grid).reshape(len(part), len(w), -1)
        out[k0 : k0 + len(part)] = np.einsum("kqn,q->kn", c, w)
        if step is not None:
            step(len(part))
    return patch.model.gain * out


#: The representative reading a rule picks λ or the TSVD rank for: a 12 mm sphere [m radius]
#: pressing this force [N] on the taxel nearest the centroid of the taxels (the centroid
#: itself can fall where modules meet, between taxels 7.5 mm away), plus the layout's noise
#: (seeded).
RULE_SPHERE_RADIUS = 6.0e-3
RULE_FORCE = 2.0
RULE_SEED = 0


def representative_reading(patch: PatchLayout, c: NDArray) -> NDArray[np.float64]:
    """Compressions [m] at the taxels that a λ or rank rule is applied to (RULE_*): the exact
    cell averages of the sphere's Hertz pressure on the patch's traction grid through C, plus
    Gaussian noise of the layout's ``noise`` [m] (without noise, GCV and the L-curve would ask
    for no regularisation at all)."""
    from tactile_contact.model.indenters import HertzSphere

    tg, _ = grids_for(patch)
    e = patch.elastomer
    xy = patch.taxel_xy()
    centre = xy[int(np.argmin(np.hypot(*(xy - xy.mean(axis=0)).T)))]
    q = HertzSphere(RULE_SPHERE_RADIUS).pressure_on_cells(
        tg.centers(), tg.half_sizes(), RULE_FORCE, centre, e.young, e.poisson
    )
    rng = np.random.default_rng(RULE_SEED)
    return c @ q + rng.normal(0.0, patch.solver.noise, c.shape[0])


def regularisation(patch: PatchLayout, c: NDArray, reg: NDArray | None) -> tuple[float, int]:
    """(absolute Tikhonov λ, TSVD rank) of the patch's solver options: a number as given
    (λ relative to the largest singular value of C), or a rule (``gcv``, ``lcurve``,
    ``discrepancy`` with the layout's ``noise``; tactile_contact.inverse.solvers.SvdInverse)
    applied to
    :func:`representative_reading`."""
    from tactile_contact.inverse.solvers import SvdInverse

    s = patch.solver
    # A rule runs only where its parameter is used (its SVD and reading cost about a second);
    # a rule the method does not use leaves λ at 0 and every singular value.
    lam_rule = isinstance(s.tikhonov, str) and s.method in ("tikhonov", "nnls_tikhonov")
    rank_rule = isinstance(s.tsvd_rank, str) and s.method == "tsvd"
    d = representative_reading(patch, c) if lam_rule or rank_rule else None
    if lam_rule:
        lam = SvdInverse(c, regulariser=reg).choose_lambda(s.tikhonov, d, noise=s.noise)
    else:
        relative = 0.0 if isinstance(s.tikhonov, str) else s.tikhonov
        lam = relative * float(np.linalg.norm(c, 2))
    if rank_rule:
        rank = SvdInverse(c).choose_rank(s.tsvd_rank, d, noise=s.noise)
    else:
        fixed = s.tsvd_rank if isinstance(s.tsvd_rank, int) else None
        rank = min(fixed or min(c.shape), *c.shape)
    return float(lam), int(rank)


def free_inverse(
    patch: PatchLayout,
    c: NDArray,
    reg: NDArray | None,
    chosen: tuple[float, int] | None = None,
) -> tuple[NDArray, float]:
    """(N, K) free inverse operator of the patch's method and the absolute λ used
    (``chosen``: λ and rank from :func:`regularisation`, computed here when None)."""
    from tactile_contact.inverse.grid_fallback import regularised_inverse

    lam, rank = chosen if chosen is not None else regularisation(patch, c, reg)
    return regularised_inverse(c, patch.solver.method, lam, reg, patch.solver.rcond, rank), lam


#: Progress steps of :func:`build_patch` after the forward matrix (one per taxel before):
#: the regularisation, the inverse, the deflection operator, the round-contact tables.
LATER_STEPS = 4


def build_patch(
    patch: PatchLayout, progress: Callable[[str, int], None] | None = None
) -> tuple[dict[str, Any], dict[str, NDArray[Any]]]:
    """Compute a patch's bundle contents: (manifest, arrays). Pure: writes nothing.

    ``progress(stage, n)`` is told when a stage starts (n = 0) and each step done: one per taxel
    of the forward matrix, then LATER_STEPS more (``len(patch.taxel_xy()) + LATER_STEPS`` in
    all)."""
    t0 = time.perf_counter()

    def done(stage: str, n: int = 1) -> None:
        if progress is not None:
            progress(stage, n)

    tg, dg = grids_for(patch)
    check_size(patch, tg, dg)
    done("forward matrix", 0)
    c = taxel_matrix(patch, tg, lambda n: done("forward matrix", n))
    reg = laplacian(tg) if patch.solver.regulariser == "laplacian" else None
    done("regularisation", 0)
    lam, rank = regularisation(patch, c, reg)
    done("inverse")
    inverse, _ = free_inverse(patch, c, reg, (lam, rank))
    done("deflection operator")
    # The output deflection is the forward model of the traction, the same one C is.
    g_out = forward_matrix(patch, dg.centers(), tg)
    done("round-contact tables")
    e = patch.elastomer
    arrays: dict[str, NDArray[Any]] = {
        "forward": c,
        "inverse": inverse.astype(np.float32),
        "deflection_operator": g_out.astype(np.float32),
        "taxel_xy": patch.taxel_xy(),
        "taxel_ids": patch.taxel_ids(),
        "traction_grid_mask": tg.mask,
        "deflection_grid_mask": dg.mask,
    }
    if reg is not None:
        arrays["regulariser"] = reg
    s, sen = patch.solver, patch.sensor
    round_step = None
    if s.refine == "round":
        from tactile_contact.inverse.round_contact import (
            DEFAULT_RADII,
            FAMILIES,
            RoundTables,
            radial_responses,
            table_step,
        )

        radii = np.asarray(DEFAULT_RADII)
        dist_step = table_step(patch.footprint)
        # The taxel readings (footprint, gain) for the fit, and the point deflection for the
        # output deflection grid (round_contact.radial_responses).
        resp = radial_responses(
            patch.layer_thickness,
            e.young,
            e.poisson,
            [patch.footprint, 0.0],
            [(f, float(a)) for f in range(len(FAMILIES)) for a in radii],
            step=dist_step,
            model=patch.model.kind,
            psi=patch.model.psi,
        )
        shape = (len(FAMILIES), len(radii), -1)
        tables = RoundTables(radii, dist_step, patch.model.gain * resp[:, 0].reshape(shape))
        arrays["round_table"] = tables.table
        arrays["round_point_table"] = resp[:, 1].reshape(shape)
        arrays["round_radii"] = tables.radii
        round_step = tables.step
    done("saving")
    params = {
        "thickness": e.thickness,
        "young": e.young,
        "poisson": e.poisson,
        "epsilon_r": sen.epsilon_r,
        "taxel_radius": sen.taxel_radius,
        "area": sen.area,
        "farad_per_count": sen.farad_per_count,
        "shift": sen.shift,
        "no_load": sen.no_load,
        "model": patch.model.kind,
        "psi": patch.model.psi,
        "taxel_average": patch.model.taxel_average,
        "footprint_radius": patch.footprint,
        "gain": patch.model.gain,
        "layer_scale": patch.model.layer_scale,
        "traction_cell": tg.cell_size,
        "deflection_cell": dg.cell_size,
        "method": s.method,
        "regulariser": s.regulariser,
        "tikhonov_relative": lam / float(np.linalg.norm(c, 2)),
        "tikhonov_rule": s.tikhonov if isinstance(s.tikhonov, str) else None,
        "tikhonov": lam,
        "rcond": s.rcond,
        "tsvd_rank": rank if s.method == "tsvd" else None,
        "tsvd_rule": s.tsvd_rank if isinstance(s.tsvd_rank, str) else None,
        "noise": s.noise,
        "contact_threshold": s.contact_threshold,
        "nnls_method": s.nnls_method,
        "support_radius": s.support_radius,
        "seed_fraction": s.seed_fraction,
        "rel_threshold": s.area_rel_threshold,
        "min_pressure": s.area_min_pressure,
        "refine": s.refine,
        "max_contacts": s.max_contacts,
        "round_step": round_step,
    }
    manifest = {
        "patch": patch.name,
        "frame_id": patch.frame_id,
        "layout_hash": patch.layout_hash(),
        "parameter_hash": patch.parameter_hash(),
        "library_version": __version__,
        "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "build_seconds": round(time.perf_counter() - t0, 3),
        "params": params,
        "layout": patch.to_dict(),
        "traction_grid": tg.as_dict(),
        "deflection_grid": dg.as_dict(),
    }
    return manifest, arrays


def _build_one(
    patch: PatchLayout,
    dest: str,
    source: str | None = None,
    progress: Callable[[str, int], None] | None = None,
) -> tuple[str, float]:
    t0 = time.perf_counter()
    manifest, arrays = build_patch(patch, progress)
    if source is not None:
        manifest["layout_source"] = source
    save_bundle(dest, manifest, arrays)
    return patch.name, time.perf_counter() - t0


def build_layout(
    layout: str | Path,
    out_dir: str | Path,
    *,
    force: bool = False,
    jobs: int | None = None,
    patches: list[str] | None = None,
    progress: bool = False,
    replaced: dict[str, str] | None = None,
) -> dict[str, str]:
    """Build the bundles of a layout file under ``out_dir``; returns patch → status
    (``built`` or ``up-to-date``). Raises LayoutError / BundleError / ValueError.

    A bundle already there and not up to date is replaced, and why goes into ``replaced``
    (patch → reason); without ``force`` one a rebuild would lose something of (calibrated,
    or made by a newer library: :func:`~tactile_contact.offline.bundle.replacing`) is refused
    before anything is built.

    ``jobs``: patches built at once, in processes (None or 1: here, one after another;
    ``tactile-contact-build`` defaults to 2). The processes start from a forkserver, which
    imports the calling script as ``__mp_main__``: a script that calls this with ``jobs > 1``
    at its top level (no ``if __name__ == "__main__":``) would run itself again in each
    process and break the pool, so from Python more than one is asked for, never assumed."""
    lay = load_layout(layout)
    # Recorded so that loading can tell when the file changed after the build.
    source = str(Path(layout).resolve())
    chosen = [lay.patch(n) for n in patches] if patches else list(lay.patches)
    out = Path(out_dir)
    status: dict[str, str] = {}
    todo = []
    for p in chosen:
        st, why = bundle_check(out / p.name, p)
        if st == "up-to-date" and not force:
            status[p.name] = "up-to-date"
            continue
        todo.append(p)
        if st != "missing":
            why = replacing(out / p.name, source, why or "--force", force)
            if replaced is not None:
                replaced[p.name] = why
    if not todo:
        return status
    bar = None
    workers = max(1, min(jobs or 1, len(todo)))
    if progress:
        from tqdm import tqdm

        if workers == 1:
            # Built here: a bar of every patch's steps (a large patch takes long).
            steps = sum(len(p.taxel_xy()) + LATER_STEPS for p in todo)
            bar = tqdm(total=steps, desc="building bundles", unit="step", file=sys.stderr)
        else:
            bar = tqdm(total=len(todo), desc="building bundles", unit="patch", file=sys.stderr)

    def step(name: str, stage: str, n: int) -> None:
        if bar is not None:
            bar.set_description(f"{name}: {stage}", refresh=False)
            bar.update(n)

    try:
        if workers == 1:
            for p in todo:
                _build_one(p, str(out / p.name), source, lambda s, n, name=p.name: step(name, s, n))
                status[p.name] = "built"
        else:
            # forkserver, not fork: the caller may be a ROS process whose DDS threads a forked
            # child would inherit in an undefined state.
            ctx = multiprocessing.get_context("forkserver")
            with cf.ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
                futs = {pool.submit(_build_one, p, str(out / p.name), source): p for p in todo}
                for fut in cf.as_completed(futs):
                    name, _ = fut.result()
                    status[name] = "built"
                    if bar is not None:
                        bar.update(1)
    finally:
        if bar is not None:
            bar.close()
    return status


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="tactile-contact-build",
        description="Build the matrix bundles (one folder per patch) of a patch layout YAML.",
    )
    ap.add_argument("layout", help="patch layout YAML (see docs/layout.md)")
    ap.add_argument("-o", "--output", required=True, help="output folder (DIR/<patch name>)")
    ap.add_argument(
        "--force",
        action="store_true",
        help="rebuild up-to-date bundles too, and replace calibrated or newer ones",
    )
    ap.add_argument("--jobs", type=int, default=None, help="parallel processes (default 2)")
    ap.add_argument("--patch", action="append", help="build only this patch (repeatable)")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    args = ap.parse_args(argv)
    if args.jobs is not None and args.jobs < 1:
        print(f"ERROR: --jobs must be >= 1, got {args.jobs}", file=sys.stderr)
        return 1
    t0 = time.perf_counter()
    replaced: dict[str, str] = {}
    try:
        status = build_layout(
            args.layout,
            args.output,
            force=args.force,
            jobs=args.jobs or 2,
            patches=args.patch,
            progress=not args.quiet,
            replaced=replaced,
        )
    except (LayoutError, BundleError, ValueError, KeyError, OSError) as exc:
        msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        print(f"ERROR: {msg}", file=sys.stderr)
        return 1
    for name, st in status.items():
        why = f"; replaced the one there: {replaced[name]}" if name in replaced else ""
        print(f"{name}: {st} ({Path(args.output) / name}){why}")
    print(f"done in {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
