"""Online reconstruction of one patch: taxel ΔC or compression δ → contacts, pressure, deflection.

:class:`Reconstructor` is loaded from a matrix bundle (built offline by
:mod:`tactile_contact.offline.build`, or calibrated by :mod:`tactile_contact.offline.calibrate`)
and runs each frame through a short chain of stages, each in its own module, doing only what
the scene needs (docs/architecture.md draws it):

1. :mod:`~tactile_contact.inverse.readings`: ΔC [F] → δ [m] per taxel, the taxels to use, the
   noise; a :class:`~tactile_contact.inverse.readings.Frame`.
2. :mod:`~tactile_contact.inverse.detection`: a bank of matched filters
   (:mod:`~tactile_contact.inverse.filter_bank`) against each taxel's noise, with a stated
   false-alarm rate. No contact → a zero result, no solve. Negative readings are signal: a
   small contact between taxels makes every nearby taxel read negative.
3. :mod:`~tactile_contact.inverse.contact_fit`: round contacts (``refine: round``, the
   default), one or up to ``max_contacts``, fitted straight to the readings, kept when they
   explain them (χ² test); the contact of the last frame is followed (``follow``).
4. :mod:`~tactile_contact.inverse.grid_fallback`: otherwise the grid solution (free inverse,
   non-negative Tikhonov where needed), with round contacts fitted around it.
5. :mod:`~tactile_contact.inverse.result`: the summary (force, CoP, area, peak) and, when
   wanted, the traction and deflection grids.

Methods ``tikhonov``, ``tsvd`` and ``pinv`` (the paper's), and ``refine: none``, use the grid
solution only. The reconstructor's state between frames is the contact it follows
(``followed``) and, with ``fuse``, the frames of the held scene
(:class:`~tactile_contact.inverse.temporal.FrameFusion`); the rest are caches.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tactile_contact.inverse.contact_fit import ContactFit, Followed, RoundContacts
from tactile_contact.inverse.detection import ASSUMED
from tactile_contact.inverse.grid_fallback import GridFallback
from tactile_contact.inverse.readings import Frame, ReadingModel
from tactile_contact.inverse.result import ContactResult, Request, ResultMaker
from tactile_contact.inverse.temporal import FrameFusion, reconstructor_fusion
from tactile_contact.model.grids import Grid
from tactile_contact.offline.bundle import Bundle, BundleCorruptError, load_bundle

__all__ = ["ContactResult", "Followed", "Reconstructor"]

#: ``solve`` without ``noise=``: ΔC off the count lattice is kept as precise readings when the
#: contact fitted to them leaves an RMS residual within this fraction of the 8-bit noise (a
#: count/√6). Exact ΔC of a matched model leaves 0.02–0.08 of it at 1–3 N; 8-bit readings,
#: whatever their baselines, leave their rounding (0.7 of it on each taxel that moved).
PRECISE_FIT = 0.1

#: Names this module held before its stages moved to modules of their own, and where they are.
_STAGE_NAMES = {
    "contact_fit": (
        "FOLLOW_FRAMES",
        "FOLLOW_SLACK",
        "FOLLOW_SLACK_SHARE",
        "ROUND_MODEL_ERROR",
    ),
    "grid_fallback": (
        "SOLVER_CACHE_SIZE",
        "FIRST_PASS_REACH",
        "FIRST_PASS_MAX_CELLS",
        "SECOND_PASS_MAX_CELLS",
        "FIT_RESIDUAL_FACTOR",
        "regularised_inverse",
        "nnls_solver",
    ),
    "filter_bank": ("DETECTION_PITCH", "DETECTION_REACH", "REFINE_PITCH", "DETECTION_PROFILES"),
    "result": ("RENDER_SUB",),
}


def __getattr__(name: str) -> Any:
    for module, names in _STAGE_NAMES.items():
        if name in names:
            import importlib
            import warnings

            new = f"tactile_contact.inverse.{module}"
            warnings.warn(
                f"{__name__}.{name} moved to {new}; import it from there",
                DeprecationWarning,
                stacklevel=2,
            )
            return getattr(importlib.import_module(new), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _grid(bundle: Bundle, key: str) -> Grid:
    g = bundle.manifest[key]
    return Grid(
        (float(g["origin"][0]), float(g["origin"][1])),
        float(g["cell"]),
        (int(g["shape"][0]), int(g["shape"][1])),
        np.asarray(bundle[f"{key}_mask"], bool),
    )


class Reconstructor:
    """Reconstruction of one patch from its bundle (see module docstring).

    Attributes:
        patch, frame_id: patch name and frame.
        taxel_xy: (K, 2) taxel centres [m], patch frame, bundle taxel order.
        taxel_ids: (K,) bus-unique taxel ids (:func:`tactile_contact.model.modules.taxel_id`).
        traction_grid, deflection_grid: :class:`tactile_contact.model.grids.Grid`.
        params: read-only mapping of the physical and solver parameters (thickness [m],
            young [Pa], poisson, epsilon_r, taxel_radius [m], area [m²], method, ...).
        forward: (K, N) matrix C [m/Pa] from traction cells to taxel compressions.
        method, noise [m], contact_threshold [m]: the bundle's solver parameters.
        readings: the sensor model (stage 1); ``full_scale`` [F], ``default_noise`` (K,) [m].
        detector: the matched-filter bank (stage 2), or None without round tables.
        contact_fit: stage 3, or None without round tables.
        grid: stage 4.
        results: stage 5.
        fit_sigma: per-taxel error [m] the grid path's round fit assumes (one count / √6).
        max_contacts: separate round contacts fitted at most (the layout's ``max_contacts``).
        follow: follow a contact from frame to frame: the last frame's single least-squares
            contact starts this frame's fit, and the multi-start search runs only when the
            followed contact does not explain the readings. For a stream of frames of one
            patch (the node); off, every frame is solved on its own and the result does not
            depend on the frames before.
        followed: the contact followed into the next frame (state), or None.
        fusion: with ``fuse``, the frames of the held scene
            (:class:`~tactile_contact.inverse.temporal.FrameFusion`): a scene that holds
            still is solved on the mean of its frames, now and then, and its result
            republished in between (``ContactResult.frames`` says how many frames it fuses);
            a change is solved at once on its own. For a stream of frames of one patch (the
            node); None: every frame is solved (the result depends on the frames before only
            through ``follow``).
    """

    def __init__(self, bundle: Bundle, *, follow: bool = False, fuse: bool = False) -> None:
        m = bundle.manifest
        self.bundle = bundle
        self.patch: str = str(m["patch"])
        self.frame_id: str = str(m.get("frame_id", self.patch))
        self.params: Mapping[str, Any] = MappingProxyType(dict(m["params"]))
        p = self.params
        self.taxel_xy = np.asarray(bundle["taxel_xy"], dtype=np.float64)
        self.taxel_ids = np.asarray(bundle["taxel_ids"], dtype=np.int64)
        self.traction_grid = _grid(bundle, "traction_grid")
        self.deflection_grid = _grid(bundle, "deflection_grid")
        self.forward = np.asarray(bundle["forward"], dtype=np.float64)
        self.method: str = str(p["method"])
        self.noise: float = float(p["noise"])
        self.contact_threshold: float = float(p["contact_threshold"])
        self.readings = ReadingModel(p, len(self.taxel_xy))
        # The round fit's per-taxel error: an 8-bit reading minus a baseline, each rounded to a
        # count, errs by two independent roundings (1/√6 count RMS); the converter noise of a
        # few tenths of a count adds little. Not ``noise``: that one also covers model error
        # for the free solution's non-negativity test.
        self.fit_sigma: float = self.readings.count_sigma
        tables = point = None
        if p.get("refine") == "round":
            from tactile_contact.inverse.round_contact import RoundTables

            tables = RoundTables.shared(
                bundle["round_radii"], float(p["round_step"]), bundle["round_table"]
            )
            if "round_point_table" in bundle.arrays:
                point = RoundTables.shared(tables.radii, tables.step, bundle["round_point_table"])
        self._round = tables
        self.detector = None
        self.contact_fit = None
        if tables is not None:
            from tactile_contact.inverse.filter_bank import patch_detector

            self.detector = patch_detector(
                tables, self.taxel_xy, self.traction_grid.cell_size, self.default_noise
            )
            self.contact_fit = ContactFit(
                tables,
                self.taxel_xy,
                self.readings.count_sigma,
                self.contact_threshold,
                int(p.get("max_contacts", 3)),
            )
        regulariser = np.asarray(bundle["regulariser"]) if "regulariser" in bundle.arrays else None
        self.grid = GridFallback(
            self.forward,
            bundle["inverse"],
            regulariser,
            self.taxel_xy,
            self.traction_grid.centers(),
            p,
            tables,
        )
        self.results = ResultMaker(
            self.traction_grid,
            self.deflection_grid,
            self.forward,
            bundle["deflection_operator"],  # memory-mapped, used on demand
            tables,
            point,
            self.taxel_xy,
            p,
        )
        self._max_contacts = int(p.get("max_contacts", 3))
        self._sigma_seen: NDArray[np.float64] | None = None
        self.follow = follow
        self.followed: Followed | None = None
        self.fusion: FrameFusion | None = None
        if fuse:
            self.fusion = reconstructor_fusion(self)

    @classmethod
    def from_bundle(
        cls,
        path: str | Path,
        expected_layout: Any = None,
        *,
        verify: bool = True,
        follow: bool = False,
        fuse: bool = False,
    ) -> Reconstructor:
        """Load the bundle at ``path`` (errors:
        :class:`tactile_contact.offline.bundle.BundleError`); ``follow`` and ``fuse`` as the
        attributes ``follow`` and ``fusion``."""
        bundle = load_bundle(path, expected_layout, verify=verify)
        try:
            return cls(bundle, follow=follow, fuse=fuse)
        except (KeyError, IndexError, TypeError, ValueError) as exc:
            # A manifest edited by hand (a key removed, a value of another type) or arrays
            # that disagree with it pass the loader's checks and fail here: one clear error.
            what = f"missing key {exc}" if isinstance(exc, KeyError) else f"{exc}"
            raise BundleCorruptError(
                f"{path}: the bundle's manifest and arrays do not make a reconstructor "
                f"({type(exc).__name__}: {what}); rebuild it with tactile-contact-build"
            ) from exc

    @property
    def n_taxels(self) -> int:
        return len(self.taxel_xy)

    @property
    def full_scale(self) -> float:
        """Largest |ΔC| [F] an 8-bit reading gives (256 counts); beyond it a taxel is
        excluded."""
        return self.readings.full_scale

    @property
    def default_noise(self) -> NDArray[np.float64]:
        """Per-taxel compression noise [m] the detector and the fit assume unless a frame
        passes its own: the layout's sensor model (the reading's rounding, one count/√6)."""
        return self.readings.default_noise

    @property
    def max_contacts(self) -> int:
        return self._max_contacts

    @max_contacts.setter
    def max_contacts(self, n: int) -> None:
        self._max_contacts = int(n)
        if self.contact_fit is not None:
            self.contact_fit.max_contacts = int(n)

    def compression(self, delta_c: ArrayLike) -> NDArray[np.float64]:
        """ΔC [F] → δ [m] with the bundle's sensor parameters (ValueError, naming it, for a
        ΔC at or below −C0 or not finite)."""
        return self.readings.compression(delta_c)

    def solve(
        self,
        delta_c: ArrayLike,
        valid: ArrayLike | None = None,
        *,
        want_traction: bool = True,
        want_deflection: bool = True,
        noise: ArrayLike | None = None,
    ) -> ContactResult:
        """Reconstruct from capacitance changes ΔC [F] (K,), bundle taxel order.

        ``valid`` (K,) bool excludes taxels. Excluded too: NaN readings, readings at or below
        −C0 (no compression explains them) and readings beyond ``full_scale`` (no 8-bit
        reading gives them: a count→farad gain or shift that differs between driver and
        bundle, or a unit mistake). ``ContactResult.taxels_used`` counts the taxels used.
        ``want_*`` False skips that output. ``noise`` [m] (scalar or (K,)): each taxel's
        compression noise (e.g. tracked online from frames without contact); default: the
        layout's sensor model (``default_noise``): ΔC taken as the skin's 8-bit readings.
        Without ``noise``, on a Reconstructor that neither follows nor fuses, ΔC off the
        count lattice is first solved as precise readings (as :meth:`solve_deflection` does),
        and that result kept when its contact explains the readings to within
        :data:`PRECISE_FIT` of the 8-bit noise (a simulation's exact ΔC; read as counts, their
        noise spread the answer along the valley: up to 20 % off, 1 N presses missed).
        """
        delta, ok = self.readings.from_delta_c(delta_c, valid)
        if (
            noise is None
            and self.fusion is None
            and not self.follow
            and not self.readings.on_count_lattice(delta, ok)
        ):
            precise = self._solve(
                Frame(
                    delta,
                    ok,
                    self.readings.default_noise,
                    quantised=False,
                    scale_free=True,
                    estimate=True,
                ),
                want_traction,
                want_deflection,
            )
            used = max(precise.taxels_used, 1)
            fit = PRECISE_FIT * self.readings.count_sigma * math.sqrt(used)
            if precise.in_contact and precise.residual_norm <= fit:
                return precise
        frame = Frame(delta, ok, self.readings.noise(noise), estimate=noise is None)
        if self.fusion is not None:
            return self.fusion.step_frame(frame, want_traction, want_deflection)
        return self._solve(frame, want_traction, want_deflection)

    def solve_deflection(
        self,
        delta: ArrayLike,
        valid: ArrayLike | None = None,
        *,
        want_traction: bool = True,
        want_deflection: bool = True,
        noise: ArrayLike | None = None,
    ) -> ContactResult:
        """Reconstruct from taxel compressions δ [m] (K,), bundle taxel order. NaN and
        compressions of the whole layer or more (δ ≥ h) are excluded like ``valid`` False.
        ``noise`` as in :meth:`solve`; without it the readings are taken as unquantised
        with unknown noise, and detection adds the scale-free test
        (:mod:`tactile_contact.inverse.detection`): a frame whose best contact explains most of
        its energy is a contact however small."""
        d, ok = self.readings.from_deflection(delta, valid)
        sigma = self.readings.noise(noise)
        # Without a noise level: readings on the 8-bit count lattice are treated as counts
        # (posterior over the quantisation valley); others as precise, of unknown noise
        # (scale-free detection, least-squares contact).
        quantised = noise is not None or self.readings.on_count_lattice(d, ok)
        frame = Frame(
            d, ok, sigma, quantised=quantised, scale_free=not quantised, estimate=noise is None
        )
        if self.fusion is not None:
            return self.fusion.step_frame(frame, want_traction, want_deflection)
        return self._solve(frame, want_traction, want_deflection)

    def _solve(self, frame: Frame, want_t: bool, want_d: bool) -> ContactResult:
        """One frame through the stages, top to bottom."""
        delta = frame.delta
        # The mean of n frames (fusion): the detector's statistics on δ·√n with one frame's
        # filters equal those on δ with σ/√n, and its filters are not rebuilt (≈ 1.7 ms).
        dz = delta if frame.frames == 1 else delta * math.sqrt(frame.frames)
        # (Excluded taxels read 0 here.)
        active = int(np.count_nonzero(np.abs(delta) > self.contact_threshold))
        request = Request(want_t, want_d, active, frame.used, time.perf_counter())
        # State: the contact followed from the last frame; this frame leaves its own (or none).
        previous = self.followed if self.follow else None
        if previous is not None and not previous.current:
            previous = None
        self.followed = None
        det, fit = self.detector, self.contact_fit
        direct = fit is not None and self.method == "nnls_tikhonov"
        contacts: RoundContacts | None = None
        start = None
        if det is not None:
            self._use_noise(frame.sigma)
            if previous is not None and direct:
                # Following: the followed contact refitted alone (no search), kept if it
                # explains the readings and its own matched filter clears the refined
                # thresholds (stricter than the bank's: the false-alarm rate holds). Why first:
                # with 24 patches each 3150 × 72 bank no longer stays in the cache (≈ 60 µs).
                found = fit.fit(frame, None, previous)
                if found is None:
                    previous = None  # it does not explain the readings: search afresh
                elif det.confirms(dz, fit.predicted(found.fits, frame.ok), frame.scale_free):
                    contacts, self.followed = found, found.followed
            if contacts is None:
                noise = ASSUMED
                if frame.estimate and frame.frames == 1:
                    # No noise level passed: the frame's own where it exceeds the assumed one
                    # (a skin noisier than its sensor model must not read as contact).
                    hit, k, noise = det.detect_estimated(dz, frame.scale_free, frame.ok)
                else:
                    hit, k = det.detect(dz, frame.scale_free)
                start = det.centres[k]
                if not hit:
                    # A near miss (a small contact between the bank's places or sizes) is
                    # fitted, and reported if the fit's own matched filter clears the refined
                    # test.
                    if direct and det.near_miss(dz, k, frame.scale_free, noise):
                        found = fit.fit(frame, start, previous)
                        if found is not None:
                            # Unconfirmed, it stays the contact to follow: what the next frame
                            # reports from it must clear the same refined test.
                            self.followed = found.followed
                            predicted = fit.predicted(found.fits, frame.ok)
                            if noise.dof:  # the noise the fitted contact leaves, not the bank
                                noise = det.residual_noise(dz, predicted, frame.ok)
                            if det.confirms(dz, predicted, frame.scale_free, noise):
                                contacts = found
                    if contacts is None:
                        return self.results.zero(request)
        elif active == 0:
            return self.results.zero(request)
        if contacts is None and start is not None and direct:
            contacts = fit.fit(frame, start, previous)
            if contacts is not None:
                self.followed = contacts.followed
        if contacts is not None:
            return self.results.of_contacts(
                contacts.fits, contacts.residual, "round", True, 0, request
            )
        grid = self.grid.solve(frame, self.readings.count_sigma, self.fit_sigma, self._max_contacts)
        if grid.fits is not None:
            residual = self.results.residual_of(grid.fits, frame)
            return self.results.of_contacts(
                grid.fits, residual, grid.path, grid.success, grid.iterations, request
            )
        return self.results.of_field(
            grid.q, frame, grid.path, grid.success, grid.iterations, request
        )

    def _use_noise(self, sigma: NDArray[np.float64]) -> None:
        """The detector's filters for the noise ``sigma`` [m] (rebuilt only when it differs:
        a tracker passes a new array when it learns)."""
        if sigma is not self._sigma_seen:
            assert self.detector is not None
            if not np.array_equal(sigma, self.detector.sigma):
                self.detector.set_noise(sigma)
            self._sigma_seen = sigma

    def warm_up(self) -> None:
        """Run each solve path once on synthetic presses, so that the compiled kernels are
        built (or loaded from numba's disk cache) now and not on the first real contact.

        Why: on a cold cache the kernels take seconds to compile, and a node that compiles
        inside its first contact frame is blind for that long (frames dropped, or late). From
        the cache this costs tens of milliseconds. No state of the reconstructor changes
        except its solver caches.
        """
        if self._round is None:
            return
        from tactile_contact.inverse.round_contact import RoundFit

        xy = self.taxel_xy
        centre = xy.mean(axis=0)
        far = xy[int(np.argmax(np.linalg.norm(xy - centre, axis=1)))]
        radius = float(np.sqrt(self._round.radii[0] * self._round.radii[-1]))

        def press(where: NDArray, family: int, force: float) -> NDArray[np.float64]:
            fit = RoundFit(force, (float(where[0]), float(where[1])), family, radius, 0.0)
            return self._round.predict(fit, xy)

        one = press(centre, 0, 1.0)
        two = one + press(far, 1, 1.0)
        # The 8-bit reading of the same press: whole counts through the sensor model.
        lattice = self.readings.from_counts(np.rint(self.readings.counts(one)))
        # A pattern no round contact explains (every other taxel pressed): the grid path.
        odd = np.where(np.arange(self.n_taxels) % 2 == 0, float(one.max()), 0.0)
        # A press one taxel of which reads 20 % more: precise readings the usual search leaves
        # unexplained, searched thoroughly (contacts.ContactFitter.unexplained).
        bent = one.copy()
        bent[int(np.argmax(np.abs(one)))] *= 1.2
        some = np.ones(self.n_taxels, dtype=bool)
        some[-1] = False
        follow, self.follow = self.follow, True  # the followed fit's kernels too
        fusion, self.fusion = self.fusion, None
        try:
            for frame in (one, two, lattice, odd, bent):
                self.solve_deflection(frame)
                self.solve_deflection(frame, noise=self.default_noise)
                self.solve_deflection(frame, some)
            if fusion is not None:  # its compiled step, and a solve of a mean of frames
                self.fusion = reconstructor_fusion(self)
                for _ in range(3):
                    self.solve_deflection(lattice, noise=self.default_noise)
        finally:
            self.follow = follow
            self.followed = None
            self.fusion = fusion
            if fusion is not None:
                fusion.reset()
