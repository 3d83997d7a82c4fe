"""Online reconstruction of one patch: taxel ΔC or compression δ → contacts, pressure, deflection.

:class:`Reconstructor` is loaded from a matrix bundle (built offline by
:mod:`tactile_contact.offline.build`, or calibrated by :mod:`tactile_contact.offline.calibrate`)
and does per
frame only what the scene needs:

1. ΔC [F] → δ [m] per taxel (:func:`tactile_contact.model.sensor.delta_c_to_compression`).
2. *Detection* (:mod:`tactile_contact.inverse.detection`): a bank of matched filters against each
   taxel's noise (passed in, e.g. tracked online by the node, or the layout's sensor model)
   with a stated false-alarm rate. No contact → a zero result, no solve. Negative readings
   are signal: a small contact between taxels makes every nearby taxel read negative.
3. *Round contacts* (``refine: round``, the default): one, or up to ``max_contacts`` separate
   ones, fitted straight to the readings through radial responses tabulated offline
   (:mod:`tactile_contact.inverse.round_contact`, :mod:`tactile_contact.inverse.contacts`): a
   compiled
   multi-start least-squares fit of centre, profile (punch- or Hertz-like, 0.4–9.6 mm) and
   force. Quantised readings (8-bit counts) report the posterior mean over the contact's
   size/centre/force valley instead of the least-squares point. Kept when they explain the
   readings to within noise and model error (χ² test).
4. Otherwise the *grid solution*: q = C⁺_λ·δ with the precomputed regularised inverse; where
   it goes negative beyond noise, two passes of non-negative Tikhonov least squares (whole
   grid, then near its strong cells: docs/reconstruction.md); then round contacts fitted
   around it replace it when they explain the readings about as well.
5. Summary (total force, CoP, area, peak) from the contacts, and, when wanted, the traction
   grid (the contacts rendered on the cells) and the deflection grid.

Methods ``tikhonov``, ``tsvd`` and ``pinv`` (the paper's), and ``refine: none``, use the grid
solution only.
"""

from __future__ import annotations

import math
import time
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from tactile_contact.inverse.contacts import CONTACT_SEED_LEVEL
from tactile_contact.inverse.summary import Contact, ContactSummary, summarize
from tactile_contact.model.grids import Grid, distance_to_points
from tactile_contact.model.sensor import (
    EPSILON_0,
    delta_c_to_compression,
    value_count_farad,
)
from tactile_contact.offline.bundle import Bundle, load_bundle


@dataclass(frozen=True)
class ContactResult:
    """Result of one frame (SI units).

    Attributes:
        traction: (rows, cols) pressure [Pa] on the traction grid (0 off the skin), or None
            when not requested.
        deflection: (rows, cols) effective deflection u_z(0) − u_z(h) [m] on the deflection
            grid, or None when not requested.
        total_force: net normal force [N].
        cop: centre of pressure (x, y) [m], patch frame; (0, 0) without contact.
        contact_area: area of the cells in contact [m²] (see
        :mod:`tactile_contact.inverse.summary`).
        peak_pressure: largest cell pressure [Pa].
        in_contact: a taxel read above the contact threshold and the solve found pressure.
        solver: which path ran: ``none`` (no contact), ``free``, ``nnls``, ``pinv``,
            ``tikhonov`` or ``tsvd``.
        success: the solver converged (False results still hold its last iterate).
        iterations: solver iterations (0 for products).
        residual_norm: ‖C·q − δ‖ [m] over the valid taxels.
        solve_time: wall time of the solve [s].
        taxels_active: valid taxels with |δ| above the contact threshold.
        refined: round contacts replaced the grid
            solution.
        taxels_used: valid taxels the solve used (those excluded: ``valid`` False, NaN, out
            of range).
        contacts: the contacts the summary adds up
        (:class:`tactile_contact.inverse.summary.Contact`):
            one per fitted round contact, else the field as one contact; empty without
            contact.
    """

    traction: NDArray[np.float64] | None
    deflection: NDArray[np.float64] | None
    total_force: float
    cop: tuple[float, float]
    contact_area: float
    peak_pressure: float
    in_contact: bool
    solver: str
    success: bool
    iterations: int
    residual_norm: float
    solve_time: float
    taxels_active: int
    refined: bool = False
    contacts: tuple[Contact, ...] = ()
    taxels_used: int = 0


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
        fit_sigma: per-taxel error [m] the round fit's posterior assumes (one count / √6).
        max_contacts: separate round contacts fitted at most (the layout's ``max_contacts``).
        full_scale: largest |ΔC| [F] an 8-bit reading gives (256 counts); beyond it a taxel
            is excluded.
    """

    def __init__(self, bundle: Bundle, *, follow: bool = False) -> None:
        m = bundle.manifest
        self.bundle = bundle
        self.patch: str = str(m["patch"])
        self.frame_id: str = str(m.get("frame_id", self.patch))
        self.params: Mapping[str, Any] = MappingProxyType(dict(m["params"]))
        self.taxel_xy = np.asarray(bundle["taxel_xy"], dtype=np.float64)
        self.taxel_ids = np.asarray(bundle["taxel_ids"], dtype=np.int64)
        self.traction_grid = _grid(bundle, "traction_grid")
        self.deflection_grid = _grid(bundle, "deflection_grid")
        self.forward = np.asarray(bundle["forward"], dtype=np.float64)
        self._inverse = np.asarray(bundle["inverse"], dtype=np.float32)
        self._deflection_op = bundle["deflection_operator"]  # memory-mapped, used on demand
        self._centers = self.traction_grid.centers()
        p = self.params
        self.method: str = str(p["method"])
        self.noise: float = float(p["noise"])
        self._thickness = float(p["thickness"])
        self.contact_threshold: float = float(p["contact_threshold"])
        self.max_contacts: int = int(p.get("max_contacts", 3))
        # Per-cell noise of the free solution, for the "violates non-negativity" test.
        self._cell_noise = self.noise * np.linalg.norm(self._inverse.astype(np.float64), axis=1)
        # Per set of valid taxels (a taxel drops out, comes back): bounded, so a flickering
        # taxel cannot grow it without end (each prepared NNLS solver holds an N × N matrix).
        self._solvers: OrderedDict[bytes, Any] = OrderedDict()
        self._seen: OrderedDict[bytes, int] = OrderedDict()
        self._round = None
        # The round fit's per-taxel error: an 8-bit reading minus a baseline, each rounded to a
        # count, errs by two independent roundings (1/√6 count RMS); the converter noise of a
        # few tenths of a count adds little. Not ``noise``: that one also covers model error
        # for the free solution's non-negativity test.
        lsb = value_count_farad(float(p["farad_per_count"]), int(p["shift"]))
        self._lsb = float(lsb)
        self._counts_per_metre_h = (
            EPSILON_0
            * float(p["epsilon_r"])
            * float(p["area"])
            / (float(p["thickness"]) * self._lsb)
        )
        # δ = ΔC·h²/(ε0·εr·A + ΔC·h) (sensor.delta_c_to_compression) per frame without its
        # argument checks: the frame's own range mask keeps the denominator positive.
        self._eps_area = EPSILON_0 * float(p["epsilon_r"]) * float(p["area"])
        self._rest_c = self._eps_area / self._thickness
        self._count_sigma = float(self.compression(np.array([lsb]))[0]) / math.sqrt(6.0)
        # The largest |ΔC| [F] a reading can carry: the 8-bit value's whole range.
        self.full_scale: float = 256.0 * lsb
        self.fit_sigma: float = self._count_sigma
        if p.get("refine") == "round":
            from tactile_contact.inverse.round_contact import RoundTables

            self._round = RoundTables.shared(
                bundle["round_radii"], float(p["round_step"]), bundle["round_table"]
            )
        self._point = None
        if self._round is not None and "round_point_table" in bundle.arrays:
            self._point = RoundTables.shared(
                self._round.radii, self._round.step, bundle["round_point_table"]
            )
        self._dg_centers = self.deflection_grid.centers()
        self._noise_cache: tuple[Any, NDArray[np.float64]] | None = None
        #: Per-taxel compression noise [m] the detector and the fit assume unless a frame
        #: passes its own: the layout's sensor model (the reading's rounding, one count/√6).
        self.default_noise = np.full(self.n_taxels, self._count_sigma)
        self.detector = self._detector() if self._round is not None else None
        self._sigma_seen: NDArray[np.float64] | None = None
        #: Follow a contact from frame to frame (:class:`Followed`): the last frame's single
        #: least-squares contact starts this frame's fit, and the multi-start search runs
        #: only when the followed contact does not explain the readings. For a stream of
        #: frames of one patch (the node); off, every frame is solved on its own and the
        #: result does not depend on the frames before.
        self.follow = follow
        self._followed: Any = None  # this frame's single contact, for the next frame
        self._previous: Any = None  # the last frame's

    def _detector(self) -> Any:
        """Matched-filter bank (:mod:`tactile_contact.inverse.detection`): round contacts of three
        sizes on a DETECTION_PITCH lattice over the skin."""
        from tactile_contact.inverse.detection import ContactDetector

        tg = self.traction_grid
        lo = self.taxel_xy.min(axis=0) - tg.cell_size
        hi = self.taxel_xy.max(axis=0) + tg.cell_size
        axes = [np.arange(lo[i], hi[i] + 1e-12, DETECTION_PITCH) for i in (0, 1)]
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 2)
        grid = grid[distance_to_points(grid, self.taxel_xy) <= DETECTION_REACH]
        dist = np.hypot(
            grid[:, None, 0] - self.taxel_xy[None, :, 0],
            grid[:, None, 1] - self.taxel_xy[None, :, 1],
        )
        rows, centres = [], []
        for fam, radius in DETECTION_PROFILES:
            rows.append(self._round.response(fam, math.log(radius), dist))
            centres.append(grid)
        # The refined test's count: every tabulated profile (both families, every radius) on a
        # REFINE_PITCH lattice, which a fitted contact stands for (the responses of 2 mm
        # electrodes change little over a quarter of a millimetre).
        per_centre = round(DETECTION_PITCH / REFINE_PITCH) ** 2
        refined = len(grid) * per_centre * self._round.table.shape[0] * len(self._round.radii)
        return ContactDetector(
            np.concatenate(rows),
            np.concatenate(centres),
            self.default_noise,
            refined_filters=refined,
        )

    def _noise(self, noise: ArrayLike | None) -> NDArray[np.float64]:
        """(K,) noise [m] for this frame: ``noise`` (scalar or (K,)) or the default."""
        if noise is None:
            return self.default_noise
        if isinstance(noise, float) and math.isfinite(noise) and noise > 0:
            # A constant level passed every frame: one array, so the detector keeps its filters.
            if self._noise_cache is None or self._noise_cache[0] != noise:
                self._noise_cache = (noise, np.full(self.n_taxels, noise))
            return self._noise_cache[1]
        # The same array as last frame (a tracker replaces its array when it learns) was
        # checked then; its values are compared, not trusted, in case it was edited since.
        cached = self._noise_cache
        if cached is not None and noise is cached[0] and (noise == cached[1]).all():
            return cached[1]
        s = np.broadcast_to(np.asarray(noise, dtype=np.float64), (self.n_taxels,))
        if not np.all(np.isfinite(s) & (s > 0)):
            raise ValueError(f"noise must be finite and > 0 m, shape () or ({self.n_taxels},)")
        if isinstance(noise, np.ndarray):
            self._noise_cache = (noise, s.copy())
            return self._noise_cache[1]
        return s

    @classmethod
    def from_bundle(
        cls,
        path: str | Path,
        expected_layout: Any = None,
        *,
        verify: bool = True,
        follow: bool = False,
    ) -> Reconstructor:
        """Load the bundle at ``path`` (errors:
        :class:`tactile_contact.offline.bundle.BundleError`);
        ``follow`` as the attribute."""
        return cls(load_bundle(path, expected_layout, verify=verify), follow=follow)

    @property
    def n_taxels(self) -> int:
        return len(self.taxel_xy)

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
        c, h = self._counts_per_metre_h, self._thickness
        counts = np.rint(c * one / (h - one))
        lattice = counts * h / (c + counts)
        # A pattern no round contact explains (every other taxel pressed): the grid path.
        odd = np.where(np.arange(self.n_taxels) % 2 == 0, float(one.max()), 0.0)
        some = np.ones(self.n_taxels, dtype=bool)
        some[-1] = False
        follow, self.follow = self.follow, True  # the followed fit's kernels too
        try:
            for frame in (one, two, lattice, odd):
                self.solve_deflection(frame)
                self.solve_deflection(frame, noise=self.default_noise)
                self.solve_deflection(frame, some)
        finally:
            self.follow = follow
            self._followed = self._previous = None

    def compression(self, delta_c: ArrayLike) -> NDArray[np.float64]:
        """ΔC [F] → δ [m] with the bundle's sensor parameters (ValueError, naming it, for a
        ΔC at or below −C0 or not finite)."""
        dc = np.asarray(delta_c, dtype=np.float64)
        h = self._thickness
        den = self._eps_area + dc * h
        if not np.all(den > 0.0):  # (NaN fails too) the checked conversion says what is wrong
            p = self.params
            return delta_c_to_compression(dc, p["thickness"], p["epsilon_r"], p["area"])
        return dc * (h * h) / den

    def _on_count_lattice(self, delta: NDArray, ok: NDArray) -> bool:
        """True when the compressions [m] are whole 8-bit counts through the sensor model
        (to 1 % of a count) and at least one is not zero."""
        # ΔC = ε0·εr·A·δ / (h·(h − δ)) (sensor.compression_to_delta_c), in counts.
        c, h = self._counts_per_metre_h, self._thickness
        # The largest reading first: off the lattice there (as float readings almost surely
        # are), the whole frame is, without converting every taxel.
        i = int(np.argmax(np.abs(delta)))
        one = c * float(delta[i]) / (h - float(delta[i]))
        if ok[i] and abs(one - round(one)) >= 0.01:
            return False
        d = delta[ok]
        counts = c * d / (h - d)
        # (max over the taxels only: an ``initial`` would take part in it.)
        return bool(np.any(np.abs(counts) > 0.5) and np.abs(counts - np.rint(counts)).max() < 0.01)

    def _check(self, x: ArrayLike, name: str, valid: ArrayLike | None) -> tuple[NDArray, NDArray]:
        v = np.asarray(x, dtype=np.float64)
        if v.shape != (self.n_taxels,):
            raise ValueError(
                f"{name} must have shape ({self.n_taxels},) in the bundle's taxel "
                f"order, got {v.shape}"
            )
        ok = np.isfinite(v)
        if valid is not None:
            mask = np.asarray(valid, dtype=bool)
            if mask.shape != (self.n_taxels,):
                raise ValueError(f"valid must have shape ({self.n_taxels},), got {mask.shape}")
            ok &= mask
        return (v if ok.all() else np.where(ok, v, 0.0)), ok

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
        layout's sensor model (``default_noise``).
        """
        dc, ok = self._check(delta_c, "delta_c", valid)
        ok &= (dc > -self._rest_c) & (np.abs(dc) <= self.full_scale)  # (NaN fails both)
        if not ok.all():
            dc = np.where(ok, dc, 0.0)
        h = self._thickness
        delta = dc * (h * h) / (self._eps_area + dc * h)
        return self._solve(delta, ok, want_traction, want_deflection, self._noise(noise), False)

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
        (:mod:`tactile_contact.inverse.detection`): a frame whose best contact explains most of its
        energy is a contact however small."""
        d, ok = self._check(delta, "delta", valid)
        ok &= d < self._thickness
        sigma = self._noise(noise)
        if not ok.all():
            d = np.where(ok, d, 0.0)
        # Without a noise level: readings on the 8-bit count lattice are treated as counts
        # (posterior over the quantisation valley); others as precise, of unknown noise
        # (scale-free detection, least-squares contact).
        quantised = noise is not None or self._on_count_lattice(d, ok)
        res = self._solve(d, ok, want_traction, want_deflection, sigma, not quantised, quantised)
        return res

    # ----------------------------------------------------------------------------------------

    def _zero(
        self, want_traction: bool, want_deflection: bool, active: int, used: int = 0
    ) -> ContactResult:
        tg, dg = self.traction_grid, self.deflection_grid
        return ContactResult(
            np.zeros(tg.shape) if want_traction else None,
            np.zeros(dg.shape) if want_deflection else None,
            0.0,
            (0.0, 0.0),
            0.0,
            0.0,
            False,
            "none",
            True,
            0,
            0.0,
            0.0,
            active,
            taxels_used=used,
        )

    def _solve(
        self,
        delta: NDArray,
        ok: NDArray,
        want_t: bool,
        want_d: bool,
        sigma: NDArray,
        scale_free: bool = False,
        quantised: bool = True,
    ) -> ContactResult:
        used = int(np.count_nonzero(ok))
        # Only a frame solved by the direct round fit leaves a contact to follow.
        self._previous, self._followed = self._followed, None
        # (Excluded taxels read 0 here.)
        active = int(np.count_nonzero(np.abs(delta) > self.contact_threshold))
        start = None
        t0 = time.perf_counter()
        fit = None
        if self.detector is not None:
            if sigma is not self._sigma_seen:
                # A new noise array (a tracker updates it now and then): new filters if it differs.
                if not np.array_equal(sigma, self.detector.sigma):
                    self.detector.set_noise(sigma)
                self._sigma_seen = sigma
            fit = self._follow_first(delta, ok, sigma, quantised, scale_free)
        if fit is None and self.detector is not None:
            hit, k = self.detector.detect(delta, scale_free)
            start = self.detector.centres[k]
            if not hit:
                fit = self._confirm(delta, ok, sigma, k, quantised, scale_free)
                if fit is None:
                    return self._zero(want_t, want_d, active, used)
        elif self.detector is None and active == 0:
            return self._zero(want_t, want_d, 0, used)
        success, iterations, path, refined = True, 0, self.method, False
        if fit is None and start is not None and self.method == "nnls_tikhonov":
            fit = self._round_direct(delta, ok, sigma, start, quantised)
        if fit is not None:
            q, path, refined = fit[0], "round", True
        else:
            q, success, iterations, path, refined, fit = self._grid(delta, ok)
        return self._result(
            q, fit, delta, ok, path, success, iterations, refined, t0, want_t, want_d, active, used
        )

    def _grid(self, delta: NDArray, ok: NDArray) -> tuple[NDArray, bool, int, str, bool, Any]:
        """The grid solution (free, then NNLS where needed), then round contacts fitted
        around it, kept if they explain the readings about as well (the path for contacts the
        direct round fit does not explain)."""
        success, iterations, path, refined = True, 0, self.method, False
        if ok.all():
            q = (self._inverse @ delta.astype(np.float32)).astype(np.float64)
        else:
            q = self._masked_free(ok) @ delta[ok]
        if self.method == "nnls_tikhonov":
            path = "free"
            # A net pull is no contact a skin can feel: it too needs the constrained solve.
            if q.sum() <= 0 or np.any(q < -3.0 * self._cell_noise):
                path = "nnls"
                q, success, iterations, refined = self._constrained(delta, ok)
        fit = None
        if self._round is not None:
            fit = self._round_fit(q, delta, ok)
            if fit is not None:
                q, refined = fit[0], True
        return q, success, iterations, path, refined, fit

    def _follow_first(
        self, delta: NDArray, ok: NDArray, sigma: NDArray, quantised: bool, scale_free: bool
    ) -> tuple[NDArray, list[Any], float] | None:
        """Following, the followed contact before the filter bank: its fit (no search), kept
        if it explains the readings and its own matched filter clears the detector's refined
        thresholds (those of every tabulated profile on a 0.25 mm lattice, stricter than the
        bank's: the false-alarm rate holds). Else None, and the frame takes the usual path;
        a followed contact that does not explain the readings is dropped for it, so it
        searches afresh at once (following again would fail again). Why: with 24 patches the
        3150 × 72 bank of each no longer stays in the cache, and reading it is ≈ 60 µs a
        frame."""
        previous = self._previous if self.follow else None
        if previous is None or previous.age >= FOLLOW_FRAMES or self.method != "nnls_tikhonov":
            return None
        fit = self._direct(delta, ok, sigma, None, quantised, previous)
        if fit is None:
            self._previous = None
            return None
        if not self.detector.confirms(delta, self._predicted(fit[1], ok), scale_free):
            self._followed = None
            return None
        return fit

    def _predicted(self, fits: list[Any], ok: NDArray) -> NDArray[np.float64]:
        """(K,) compressions [m] of the contacts ``fits``, 0 at the taxels not ``ok``."""
        predicted = np.zeros(self.n_taxels)
        for contact in fits:
            predicted += self._round.predict(contact, self.taxel_xy)
        predicted[~ok] = 0.0
        return predicted

    def _confirm(
        self, delta: NDArray, ok: NDArray, sigma: NDArray, k: int, quantised: bool, scale_free: bool
    ) -> tuple[NDArray, list[Any], float] | None:
        """A frame the filter bank just missed: the round contacts fitted from the bank's best
        place (as :meth:`_round_direct`), or None unless their own matched filter clears the
        detector's refined thresholds. Why: the bank holds five sizes on a 2 mm lattice, and a
        small contact between two taxels, read precisely, matches none of them well (a 0.2 N
        6 mm sphere: 35 % of the frame's energy explained by the best bank filter, 99.6 % by
        the fitted contact)."""
        det = self.detector
        if self.method != "nnls_tikhonov" or not det.near_miss(delta, k, scale_free):
            return None
        fit = self._round_direct(delta, ok, sigma, det.centres[k], quantised)
        if fit is None:
            return None
        # An unconfirmed fit stays the contact to follow: the next frame starts from it, and
        # what that frame reports must clear the same refined test (the false-alarm bound
        # holds). Dropping it made the test sweep search more often (64 against ≤ 59).
        return fit if det.confirms(delta, self._predicted(fit[1], ok), scale_free) else None

    def _round_direct(
        self, delta: NDArray, ok: NDArray, sigma: NDArray, start: NDArray, posterior: bool
    ) -> tuple[NDArray, list[Any], float] | None:
        """Round contacts fitted straight to the readings from the detector's best place, or
        None when they do not explain the readings to within noise and model error (χ² test):
        then the grid path runs. Following (``follow``), a frame that the followed contact
        does not explain is searched afresh before it is given up."""
        previous = self._previous if self.follow else None
        if previous is not None and previous.age >= FOLLOW_FRAMES:
            previous = None
        out = self._direct(delta, ok, sigma, start, posterior, previous)
        if out is None and previous is not None:
            out = self._direct(delta, ok, sigma, start, posterior, None)
        return out

    def _direct(
        self,
        delta: NDArray,
        ok: NDArray,
        sigma: NDArray,
        start: NDArray | None,
        posterior: bool,
        previous: Followed | None,
    ) -> tuple[NDArray, list[Any], float] | None:
        from tactile_contact.inverse.contacts import ContactFitter, chi2, chi2_limit
        from tactile_contact.inverse.round_contact import follow_round_contact

        xy, d, s = self.taxel_xy[ok], delta[ok], sigma[ok]
        limit = chi2_limit(len(d))
        fits, followed = None, None
        if previous is not None:
            # The posterior spans both families anyway: only the followed one is fitted.
            single = follow_round_contact(
                self._round, xy, d, previous.fit, sigma=s, other_family=not posterior
            )
            if single is not None:
                pred = self._round.predict(single, xy)
                misfit = chi2(pred, d, s, ROUND_MODEL_ERROR)
                slack = FOLLOW_SLACK + FOLLOW_SLACK_SHARE * previous.misfit
                if misfit <= min(limit, previous.misfit + slack):
                    fits = [single]
                    followed = Followed(single, previous.misfit, previous.age + 1)
        fitter = ContactFitter(
            self._round, self._count_sigma, self.contact_threshold, s, self.max_contacts
        )
        if fits is None:
            if start is None:  # following only (_follow_first)
                return None
            found = fitter.fit(xy, d, np.asarray(start, dtype=np.float64))
            if found is None:
                return None
            fits = found[0]
            pred = fitter.predicted(fits, xy)
            misfit = chi2(pred, d, s, ROUND_MODEL_ERROR)
            if misfit > limit:
                return None
            if len(fits) == 1:
                followed = Followed(fits[0], misfit, 0)
        if posterior and len(fits) == 1:
            # Quantised readings: report the posterior mean over the size/centre/force valley
            # (round_contact.posterior_contact) instead of the least-squares point. Its error is
            # the rounding's (one count/√6), not the learnt noise level: unless the contact is
            # followed, the same readings give the same contact whatever frames came before.
            from tactile_contact.inverse.round_contact import posterior_contact

            fits = [posterior_contact(self._round, xy, d, fits[0], self._count_sigma)]
            pred = fitter.predicted(fits, xy)
        # The test above is on the least-squares fit (the least χ² the model reaches), not on
        # the posterior mean: the mean of a curved valley lies off its floor, and on the load
        # bench's 12 mm sphere it missed the test by a few percent where the fit passed it
        # (χ² 138 against 86, limit 132), sending good frames to the slower grid path.
        self._followed = followed
        return self._render(fits), fits, float(np.linalg.norm(pred - d))

    def _render(self, fits: list[Any]) -> NDArray[np.float64]:
        """Pressure [Pa] of the round contacts ``fits`` on the traction grid: the mean over
        RENDER_SUB² points per cell, scaled so that each contact's cells carry its force (the
        flat punch's integrable edge singularity makes point means uneven, not wrong in sum;
        a part beyond the skin mask lands on the cells at its edge)."""
        from tactile_contact.inverse._round_kernels import render
        from tactile_contact.inverse.round_contact import FAMILIES

        out = np.zeros(len(self._centers))
        cell = self.traction_grid.cell_size
        for f in fits:
            punch = FAMILIES[f.family] == "punch"
            render(self._centers, cell, RENDER_SUB, *f.center, f.radius, f.force, punch, out)
        return out

    def _deflection_of(self, fits: list[Any]) -> NDArray[np.float64]:
        """(cells,) effective deflection [m] of the round contacts on the deflection grid's
        cells, from the point-response tables (true deflection: no taxel gain)."""
        out = np.zeros(len(self._dg_centers))
        for fit in fits:
            out += self._point.predict(fit, self._dg_centers)
        return out

    def _result(
        self,
        q: NDArray,
        fit: Any,
        delta: NDArray,
        ok: NDArray,
        path: str,
        success: bool,
        iterations: int,
        refined: bool,
        t0: float,
        want_t: bool,
        want_d: bool,
        active: int,
        used: int,
    ) -> ContactResult:
        dt = time.perf_counter() - t0
        if fit is not None and len(fit) == 3:
            residual = fit[2]  # the direct fit's own (tables), not its 2 mm-cell rendering's
        elif fit is not None:
            pred = sum(self._round.predict(f, self.taxel_xy[ok]) for f in fit[1])
            residual = float(np.linalg.norm(pred - delta[ok]))
        else:
            residual = float(np.linalg.norm((self.forward @ q - delta)[ok]))
        min_pressure = float(self.params["min_pressure"])
        if fit is None:
            s = summarize(
                q,
                self._centers,
                self.traction_grid.cell_area,
                float(self.params["rel_threshold"]),
                min_pressure,
            )
            contacts = (Contact.of_field(s),) if s.in_contact else ()
        else:
            # The fit's own force, centre and disc, not their 2 mm-cell rendering (which
            # loses the part of a contact beyond the skin mask and blurs a small disc); of
            # the rendering only the peak, and whether any cell clears min_pressure (as
            # summarize would find it: a cell above the threshold exists iff the peak is).
            from tactile_contact.inverse.round_contact import FAMILIES

            contacts = tuple(
                Contact(f.force, f.center, f.radius, FAMILIES[f.family]) for f in fit[1]
            )
            force = sum(c.force for c in contacts)
            cop = sum(c.force * np.asarray(c.center) for c in contacts) / force
            peak = max(float(q.max(initial=0.0)), 0.0)
            s = ContactSummary(
                force,
                (float(cop[0]), float(cop[1])),
                sum(math.pi * c.radius**2 for c in contacts),
                peak,
                peak > min_pressure,
            )
        deflection = None
        if want_d:
            dg = self.deflection_grid
            if fit is not None and self._point is not None:
                deflection = dg.to_image(self._deflection_of(fit[1]))
            else:
                deflection = dg.to_image(
                    np.asarray(self._deflection_op, np.float32) @ q.astype(np.float32)
                ).astype(np.float64)
        return ContactResult(
            self.traction_grid.to_image(q) if want_t else None,
            deflection,
            s.total_force,
            s.cop,
            s.contact_area,
            s.peak_pressure,
            s.in_contact,
            path,
            success,
            iterations,
            residual,
            dt,
            active,
            refined,
            contacts,
            taxels_used=used,
        )

    def _cached(self, key: bytes) -> Any:
        """The cached operator or solver under ``key`` (None if absent), now most recent."""
        if key not in self._solvers:
            return None
        self._solvers.move_to_end(key)
        return self._solvers[key]

    def _cache(self, key: bytes, value: Any) -> Any:
        self._solvers[key] = value
        while len(self._solvers) > SOLVER_CACHE_SIZE:
            self._solvers.popitem(last=False)
        return value

    def _recurring(self, key: bytes) -> bool:
        """True from the second frame with this set of valid taxels on (counted for the last
        SOLVER_CACHE_SIZE sets): a set met once, a taxel flickering out for one frame, is not
        worth a prepared solver's N³ set-up."""
        n = self._seen.pop(key, 0) + 1
        self._seen[key] = n
        while len(self._seen) > 4 * SOLVER_CACHE_SIZE:
            self._seen.popitem(last=False)
        return n >= 2

    def _masked_free(self, ok: NDArray) -> NDArray[np.float64]:
        """Free inverse for a subset of taxels (cached per subset; rows of C dropped)."""
        key = b"free" + np.packbits(ok).tobytes()
        inverse = self._cached(key)
        if inverse is None:
            p = self.params
            a = self.forward[ok]
            rank = min(int(p["tsvd_rank"] or min(a.shape)), *a.shape)
            inverse = self._cache(
                key,
                regularised_inverse(
                    a,
                    self.method,
                    float(p["tikhonov"]),
                    self._regulariser(),
                    float(p["rcond"]),
                    rank,
                ),
            )
        return inverse

    def _regulariser(self) -> NDArray[np.float64] | None:
        return (
            np.asarray(self.bundle["regulariser"]) if "regulariser" in self.bundle.arrays else None
        )

    def _nnls(
        self, cols: NDArray | None, ok: NDArray, delta: NDArray, warm: bool, method: str = ""
    ):
        key = np.packbits(ok).tobytes() + (b"" if cols is None else np.packbits(cols).tobytes())
        solver = self._cached(key) if warm else None
        if solver is None:
            a = self.forward[ok] if cols is None else self.forward[np.ix_(ok, cols)]
            reg = self._regulariser()
            if reg is not None and cols is not None:
                reg = reg[:, cols]
            solver = nnls_solver(
                a, float(self.params["tikhonov"]), reg, method or str(self.params["nnls_method"])
            )
            if warm and (ok.all() or self._recurring(key)):
                # Kept across frames: the one-off work (H⁻¹ on the Gram route) pays off.
                self._cache(key, solver.prepare())
        res = solver.solve(delta[ok], warm_start=warm)
        return np.asarray(res.x, dtype=np.float64), bool(res.success), int(res.iterations)

    def _constrained(self, delta: NDArray, ok: NDArray) -> tuple[NDArray, bool, int, bool]:
        # First pass on the cells near the taxels that read a contact, when they are few (one
        # or two presses): a small cold problem for scipy (~0.3 ms) instead of pivoting over the
        # whole grid (~1.1 ms); the pressure it leaves out lies under taxels reading nothing.
        xy, d = self.taxel_xy[ok], delta[ok]
        lit = d > CONTACT_SEED_LEVEL * self.contact_threshold
        near = None
        if lit.any():
            near = distance_to_points(self._centers, xy[lit]) <= FIRST_PASS_REACH
        if near is not None and 0 < near.sum() <= FIRST_PASS_MAX_CELLS:
            q1 = np.zeros(len(self._centers))
            q1[near], s1, it1 = self._nnls(near, ok, delta, warm=False, method="lawson_hanson")
        else:
            q1, s1, it1 = self._nnls(None, ok, delta, warm=True)
        peak = q1.max(initial=0.0)
        if peak <= 0:
            return q1, s1, it1, False
        seeds = self._centers[q1 >= float(self.params["seed_fraction"]) * peak]
        cols = distance_to_points(self._centers, seeds) <= float(self.params["support_radius"])
        if cols.sum() > SECOND_PASS_MAX_CELLS:
            # Seeds all over the grid (a faint frame: pressure spread thin): the support is no
            # smaller than the first pass's, and scipy on 500 columns takes 40-50 ms.
            return q1, s1, it1, False
        # The support is a few tens of cells, solved once: scipy's Lawson–Hanson on the
        # stacked system beats building a pivoting route in Python (~50 vs ~350 µs).
        q2, s2, it2 = self._nnls(cols, ok, delta, warm=False, method="lawson_hanson")
        q = np.zeros_like(q1)
        q[cols] = q2
        return q, s1 and s2, it1 + it2, False

    def _round_fit(
        self, q: NDArray, delta: NDArray, ok: NDArray
    ) -> tuple[NDArray, list[Any]] | None:
        """Round contacts (:class:`tactile_contact.inverse.contacts.ContactFitter`): (their cell
        averages on the traction grid, the fits), or None when they explain the data clearly
        worse than the grid solution q."""
        from tactile_contact.inverse.contacts import ContactFitter

        xy, d = self.taxel_xy[ok], delta[ok]
        pos = q > 0
        cop = (q[pos] @ self._centers[pos]) / q[pos].sum() if pos.any() else None
        fitter = ContactFitter(
            self._round,
            self._count_sigma,
            self.contact_threshold,
            sigma=self.fit_sigma if self.fit_sigma > 0 else None,
            max_contacts=self.max_contacts,
        )
        found = fitter.fit(xy, d, cop)
        if found is None:
            return None
        fits, residual = found
        r_grid = float(np.linalg.norm(self.forward[ok] @ q - d))
        if residual > FIT_RESIDUAL_FACTOR * r_grid + self.noise * math.sqrt(ok.sum()):
            return None
        return self._render(fits), fits


@dataclass(frozen=True)
class Followed:
    """A single contact followed from frame to frame (``Reconstructor.follow``).

    Attributes:
        fit: its least-squares fit in the last frame.
        misfit: :func:`tactile_contact.inverse.contacts.chi2` of the fit that the last full search
            found; a followed fit may exceed it by FOLLOW_SLACK + FOLLOW_SLACK_SHARE of it.
        age: frames followed since that search.
    """

    fit: Any
    misfit: float
    age: int


#: A followed contact is searched afresh after this many frames (0.5 s at 50 Hz): a followed
#: fit stays in the basin it started in, and the full search may have found a deeper one.
#: (Load-bench frames: the same force and CoP errors for 10, 25 and 50.)
FOLLOW_FRAMES = 25
#: A followed fit whose χ² exceeds that of the last full search by more than this is searched
#: afresh. The χ² test alone is lenient (most 8-bit readings of a small contact are exact
#: zeros: χ² ≈ 10 against a limit of 132 for 72 taxels), and a followed fit at χ² 74 where the
#: search found 9 reported 0.5 N for 1.5 N.
FOLLOW_SLACK = 10.0
#: ... plus this share of that χ²: a strong press misfits by model error (χ² 65-100 on the
#: load bench's 2 N sphere), which changes by 10-30 from frame to frame as it slides; with
#: the fixed slack alone, 9 % of its frames were searched again for nothing.
FOLLOW_SLACK_SHARE = 0.3

#: Operators and solvers kept, one per set of valid taxels (and pass): the full set and a few
#: sets with taxels out. Each prepared NNLS solver holds N × N float64 (2.6 MB at N = 568).
SOLVER_CACHE_SIZE = 8

#: The grid path's first NNLS pass keeps the cells within this distance [m] of the taxels
#: reading a contact (above CONTACT_SEED_LEVEL thresholds), when they are at most
#: FIRST_PASS_MAX_CELLS; else it solves the whole grid. Chosen on the bench's fallback frames:
#: forces as the whole-grid pass gave them, 1.7-1.9 instead of 2.3-2.9 ms per frame.
FIRST_PASS_REACH = 6.0e-3
FIRST_PASS_MAX_CELLS = 150
#: The second pass (near the first pass's strong cells) runs only on this many cells at most.
SECOND_PASS_MAX_CELLS = 150

#: Lattice pitch [m] of the detector's bank, and how far beyond a taxel it reaches [m].
DETECTION_PITCH = 2.0e-3
DETECTION_REACH = 4.0e-3
REFINE_PITCH = 0.25e-3
#: Bank profiles (family index into round_contact.FAMILIES, contact radius [m]): small to
#: broad punches and spheres. Without the 6.5 mm punch a 12 mm flat punch read by point-like
#: taxels explained only 35 % of its frame's energy and light presses of it went unseen.
DETECTION_PROFILES = ((0, 1.0e-3), (1, 2.5e-3), (0, 4.0e-3), (1, 5.0e-3), (0, 6.5e-3))
#: Sub-samples per cell edge when round contacts are rendered on the traction grid.
RENDER_SUB = 4
#: Relative model error [-] the direct round fit's χ² test allows on top of the noise (the
#: tables against a finer forward model: 1–4 %).
ROUND_MODEL_ERROR = 0.05

#: Round contacts fitted around the grid solution are kept only if their residual is at most
#: this factor times the grid solution's plus the noise.
FIT_RESIDUAL_FACTOR = 1.5


# --- solver access (tactile_contact.inverse.solvers)
# -----------------------------------------------


def regularised_inverse(
    matrix: NDArray, method: str, lam: float, reg: NDArray | None, rcond: float, rank: int
) -> NDArray[np.float64]:
    """(N, K) free inverse: ``pinv`` (rcond), ``tsvd`` (rank) or Tikhonov (λ, regulariser L),
    all from one SVD (:class:`tactile_contact.inverse.solvers.SvdInverse`)."""
    from tactile_contact.inverse.solvers import SvdInverse

    inv = SvdInverse(matrix, regulariser=reg)
    if method == "pinv":
        return np.asarray(inv.pinv_operator(rcond), dtype=np.float64)
    if method == "tsvd":
        return np.asarray(inv.tsvd_operator(rank), dtype=np.float64)
    return np.asarray(inv.tikhonov_operator(lam), dtype=np.float64)


def nnls_solver(matrix: NDArray, tikhonov: float, regulariser: NDArray | None, method: str) -> Any:
    """A warm-startable solver of min ‖Ax − d‖² + λ²‖Lx‖², x ≥ 0 (NnlsSolver)."""
    from tactile_contact.inverse.solvers import NnlsSolver

    return NnlsSolver(matrix, tikhonov=tikhonov, regulariser=regulariser, method=method)
