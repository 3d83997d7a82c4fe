"""Round contacts of one frame: one, or several separate ones, fitted to the taxel readings.

The reconstructor's default refinement (``refine: round``). Each contact is a round contact
of :mod:`tactile_contact.inverse.round_contact` (family, radius, force, centre), reported by its
posterior mean. Several are fitted only where the readings call for them: taxels reading well
above the contact threshold, far apart and parted by a dip in the readings between them seed
one contact each, a contact too light for that is seeded where the contacts already fitted
leave readings unexplained, and separate contacts replace fewer only if they explain the
readings better by more than the extra parameters fitted to noise would.

All lengths in metres, forces in newtons, readings as compressions δ [m]. No ROS import.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from tactile_contact.inverse.detection import ROBUST_CAP, robust_scale
from tactile_contact.inverse.round_contact import (
    RoundFit,
    RoundTables,
    fit_round_contact,
    hop_round_contact,
)
from tactile_contact.model.grids import distance_to_points

#: Taxels closer than this [m] seed one contact between them: the 5.5 mm taxel pitch cannot
#: tell two contacts that close apart.
CONTACT_SEPARATION = 8.0e-3
#: A taxel seeds a separate contact only above this many contact thresholds (≈ 2.6 counts):
#: through the driver an idle taxel reads up to about 1.7 counts (its baseline offset, the
#: converter noise), and seeding there split one pressed sphere into three contacts.
CONTACT_SEED_LEVEL = 2.5
#: A contact too light to seed from the readings is seeded from what the others leave
#: (ContactFitter.from_residual) above this many contact thresholds (≈ 2.2 counts); the
#: evidence margin below still decides. Not lower: the driver leaves idle taxels up to ≈ 1.7
#: counts of baseline offset, which the tracked noise does not hold — at 1.0 the recorded
#: session's single sphere came back with ghosts of 1.2 and 4.3 N beside it.
RESIDUAL_SEED_LEVEL = 2.0
#: ... and at least this far [m] from every contact already fitted: nearer, the tables' own
#: error around a strong press (its bulge ring reaches about 12 mm) stands out of the
#: residual as much (a 3 N, 3 mm punch split off a 0.5 N contact 8 mm beside it).
RESIDUAL_APART = 12.0e-3
#: Width [m] (σ of a Gaussian in distance) of the neighbourhood whose residual energy seeds a
#: contact from the residual: about the taxel pitch (5.5-6.5 mm), so a taxel's neighbours weigh
#: a quarter to a third of it.
RESIDUAL_WIDTH = 4.0e-3
#: The residual's energy is weighed around this many free taxels, those it is largest at.
RESIDUAL_CANDIDATES = 16
#: Separate contacts replace the single one only if they lower the squared residual by more
#: than this many σ² (σ = one count/√6, the reading's rounding error): each adds four
#: parameters, and noise alone lowers it by about 4σ² for those (χ², 4 degrees of freedom;
#: 99.9 % below 18.5).
MULTI_CONTACT_EVIDENCE = 25.0
#: Readings farther than this [m] from the strongest one do not pull the second search start:
#: there, idle taxels read a count or two of baseline offset.
START_REACH = 12.0e-3
#: The second search start is used only when it is farther than this [m] from the first.
START_APART = 1.5e-3
#: A fitted contact must press within this distance [m] of the hull of the taxel centres: the
#: skin ends 1.5–2 mm beyond its outer taxels. Beyond, a fit explains noise with a contact no
#: taxel reads (1 count of noise: 10.8 N fitted 6.4 mm off the patch for a 2.3 N press).
SKIN_MARGIN = 2.0e-3
#: Taxels within this distance [m] of a search start are fitted (round_contact's ``near``).
REACH = 0.015
#: The search's check (ContactFitter.unexplained) takes the noise from the taxels beyond
#: REACH when there are at least this many.
FAR_TAXELS = 6
#: ... and at least this share of the largest |reading| (precise readings: model error).
PRECISE_FLOOR = 1.0e-3
#: Relative model error [-] the search's check allows: the tables against a finer forward
#: model err by 0.1–1 % away from a contact's edge (more at a point taxel on a punch's edge,
#: which then costs a thorough search for nothing).
SEARCH_MODEL_ERROR = 0.01
#: Readings within this distance [m] of the largest |reading| weigh the magnitude centroid (a
#: start): the bulge ring around a contact reaches about 12 mm; beyond, idle taxels' noise
#: only pulls it towards the patch's middle.
MAGNITUDE_REACH = 20.0e-3


@dataclass(frozen=True)
class ContactFitter:
    """Fits the round contacts of one frame.

    Attributes:
        tables: the bundle's radial responses.
        count_sigma: rounding error [m] of one reading (one count/√6 through the sensor
            model: a reading and its baseline, each rounded to a count); the unit of
            MULTI_CONTACT_EVIDENCE.
        contact_threshold: compression [m] above which a taxel reads contact.
        sigma: per-taxel error [m] (scalar or per taxel) weighting the fit, or None for equal
            weights; with ``precise`` False also the least noise the search's check assumes.
        max_contacts: separate contacts fitted at most.
        precise: the readings are precise values of unknown noise (not 8-bit counts): the
            search's check (:meth:`unexplained`) takes their noise from the taxels the fit
            leaves out, however small.
        estimate_noise: the caller passed no noise level: separate contacts must win by
            MULTI_CONTACT_EVIDENCE of the noise the single contact leaves on the far taxels
            (:meth:`far_noise`) when that exceeds ``count_sigma``, and seed above as many
            times the contact threshold (with 1 count of noise, the assumed 0.4 let noise
            seed and win extra contacts).
    """

    tables: RoundTables
    count_sigma: float
    contact_threshold: float
    sigma: float | NDArray | None = None
    max_contacts: int = 3
    precise: bool = False
    estimate_noise: bool = False

    def fit(
        self, xy: NDArray, d: NDArray, cop: NDArray | None
    ) -> tuple[list[RoundFit], float] | None:
        """(contacts, residual [m] of the least-squares points) for readings d [m] at taxels
        xy [m], searched around ``cop`` (the grid solution's centre of pressure, or None), or
        None when no round contact has a positive force."""
        start = self.starts(cop, xy, d)
        single = fit_round_contact(self.tables, xy, d, start, sigma=self.sigma)
        if single is not None and self.precise and self.unexplained(single, xy, d, start):
            # A false valley, or a contact the usual search did not reach: search wider. (Only
            # precise readings: with 8-bit counts the noise blurs the valleys the search tells
            # apart, 0 of 200 random presses triggered it, and on noise alone it only cost.)
            for again in (
                fit_round_contact(self.tables, xy, d, start, sigma=self.sigma, thorough=True),
                hop_round_contact(self.tables, xy, d, single, sigma=self.sigma),
            ):
                if again is not None and self._misfit(again, xy, d) < self._misfit(single, xy, d):
                    single = again
        fits = [single] if single is not None else []
        residual = single.residual if single is not None else math.inf
        # The evidence is weighed in the readings' noise: the rounding's at least, the noise
        # passed in (a tracked level) where larger, or the one measured on the far taxels.
        level = self.count_sigma
        if self.sigma is not None:
            level = max(level, float(np.sqrt(np.mean(np.square(self.sigma)))))
        if self.estimate_noise and single is not None:
            level = max(level, self.far_level(single, xy, d) or 0.0)
        # Separate contacts must lower the squared residual by the evidence margin: a single
        # contact already within it leaves nothing to win (and skips 4-5 more fits).
        margin = MULTI_CONTACT_EVIDENCE * level**2
        seeds = (
            [xy[i] for i in self.seeds(xy, d, level / self.count_sigma)]
            if residual**2 > margin
            else []
        )
        points: list[RoundFit] = []
        if len(seeds) > 1:
            # Model choice on least-squares points (their residuals are those of the
            # predictions subtracted); the posterior then reports each contact.
            points = self.least_squares(seeds, xy, d)
            kept = spread(points, CONTACT_SEPARATION)
            if 1 < len(kept) < len(points):
                # Two seeds under one broad contact (a 12 mm punch reads alike under its
                # face) fitted one contact twice: refit from the contacts that stand apart
                # rather than give up the separate ones.
                points = self.least_squares([f.center for f in kept], xy, d)
            if len(points) < 2 or not apart(points, CONTACT_SEPARATION):
                points = []
        r_one = residual
        if points:
            r_multi = float(np.linalg.norm(d - self.predicted(points, xy)))
            if r_one**2 - r_multi**2 > margin:
                # The unweighted single fit may explain more than the weighted one.
                one = fit_round_contact(self.tables, xy, d, start, polish=False)
                r_one = min(one.residual if one is not None else math.inf, residual)
            if r_one**2 - r_multi**2 <= margin:
                points = []
        if single is not None and residual**2 > margin and len(points) < self.max_contacts:
            # A contact too light to seed from the readings (its strongest taxel under
            # CONTACT_SEED_LEVEL, often beside a strong one) still stands out of what the
            # contacts already fitted leave: seed from that residual, under the same evidence.
            base = points or [single]
            peak = self.residual_peak(base, xy, d, level)
            if peak is not None:
                if not points:  # the least-squares point the separate ones are weighed against
                    one = fit_round_contact(self.tables, xy, d, start, polish=False)
                    base = [one] if one is not None else []
                    r_one = one.residual if one is not None else math.inf
                    peak = None  # (weighed again against that point)
                r2 = min(r_one, residual) ** 2 if not points else None
                more = self.from_residual(base, xy, d, level, margin, r2, peak) if base else []
                if len(more) > max(len(points), 1):
                    points = more
        if len(points) > 1:
            fits, residual = [], float(np.linalg.norm(d - self.predicted(points, xy)))
            for k, f in enumerate(points):
                rest = d - self.predicted(points, xy, skip=k)
                post = fit_round_contact(self.tables, xy, rest, f.center, sigma=self.sigma)
                fits.append(post if post is not None else f)
        return (fits, residual) if fits else None

    def from_residual(
        self,
        points: list[RoundFit],
        xy: NDArray,
        d: NDArray,
        level: float,
        margin: float,
        r2: float | None = None,
        peak: int | None = None,
    ) -> list[RoundFit]:
        """``points`` (least-squares contacts) and, one at a time up to ``max_contacts``,
        a contact seeded at the taxel around which the others leave the most residual energy
        (:meth:`residual_peak`), kept when the contacts refitted together lower the squared
        residual by more than ``margin`` [m²] (against ``r2`` [m²], by default the squared
        residual of ``points``); ``peak``: the first seed's taxel when already found for
        ``points``."""
        if r2 is None:
            r2 = float(np.sum(np.square(d - self.predicted(points, xy))))
        while len(points) < self.max_contacts:
            i = self.residual_peak(points, xy, d, level) if peak is None else peak
            peak = None
            if i is None:
                break
            rest = d - self.predicted(points, xy)
            # Started at that taxel and at the centre of the residual's magnitude around it:
            # a contact read as its bulge lies inside the ring of taxels it pushes down.
            off = xy - xy[i]
            around = np.hypot(off[:, 0], off[:, 1]) <= RESIDUAL_WIDTH * 2.5
            size = np.abs(rest[around])
            starts = xy[i][None, :]
            if size.sum() > 0.0:
                starts = np.array([xy[i], (size @ xy[around]) / size.sum()])
            new = fit_round_contact(self.tables, xy, rest, starts, polish=False)
            if new is None:
                break
            trial = self.least_squares([f.center for f in points] + [new.center], xy, d)
            if len(trial) <= len(points) or not apart(trial, CONTACT_SEPARATION):
                break
            r2_trial = float(np.sum(np.square(d - self.predicted(trial, xy))))
            if r2 - r2_trial <= margin:
                break
            points, r2 = trial, r2_trial
        return points

    def residual_peak(
        self, points: list[RoundFit], xy: NDArray, d: NDArray, level: float
    ) -> int | None:
        """The taxel (index into xy) at least RESIDUAL_APART from each of the contacts
        ``points`` around which their residual's energy (Σ of squared residuals weighted by a
        Gaussian of RESIDUAL_WIDTH in distance) is largest, when that energy exceeds the
        square of RESIDUAL_SEED_LEVEL contact thresholds times ``level``/σ (the readings' noise
        over the assumed one, at least 1); else None.

        Why energy, not the largest reading: a small contact between taxels reads mostly as
        its bulge, negative all round (a 3 mm punch at 2 N, 16 mm from a strong one, left no
        residual above a count); and a contact's readings spread over its neighbours where
        one taxel's baseline offset does not."""
        floor = RESIDUAL_SEED_LEVEL * max(level / self.count_sigma, 1.0) * self.contact_threshold
        free = distance_to_points(xy, np.array([f.center for f in points])) >= RESIDUAL_APART
        if not free.any():
            return None
        rest2 = np.square(d - self.predicted(points, xy))
        # (The energy peaks at one of the free taxels the residual is largest at: weighing
        # those alone costs a fraction of every free taxel's.)
        idx = np.flatnonzero(free)
        if len(idx) > RESIDUAL_CANDIDATES:
            idx = idx[np.argpartition(-rest2[idx], RESIDUAL_CANDIDATES)[:RESIDUAL_CANDIDATES]]
        energy = neighbourhood(xy)[idx] @ rest2
        best = int(np.argmax(energy))
        return int(idx[best]) if energy[best] > floor**2 else None

    def unexplained(self, fit: RoundFit, xy: NDArray, d: NDArray, start: NDArray) -> bool:
        """Whether the least-squares contact ``fit`` leaves readings unexplained by noise: its
        χ² over the taxels it was fitted to (within REACH of a start) exceeds
        :func:`chi2_limit`, against their noise (``sigma``, at least; or, ``precise``, only)
        as the taxels left out read it after the fit (their mean square residual, when at
        least FAR_TAXELS) and a relative model error of SEARCH_MODEL_ERROR.

        Why: the search ends in a false valley now and then (a contact's size, family and
        centre trade off along narrow valleys), and there its residual stands above the
        noise; the taxels beyond the fit's reach measure that noise without being fitted."""
        pred = self.tables.predict(fit, xy)
        res = pred - d
        fitted = distance_to_points(xy, start) <= REACH
        far = ~fitted
        noise2 = np.zeros(len(d))
        if self.sigma is not None and not self.precise:
            noise2 = np.broadcast_to(np.square(self.sigma), d.shape)
        if far.sum() >= FAR_TAXELS:
            noise2 = np.maximum(noise2, float(np.mean(np.square(res[far]))))
        # Precise readings of a contact the tables model exactly leave a zero residual: some
        # noise floor keeps the test finite.
        noise2 = np.maximum(noise2, (PRECISE_FLOOR * float(np.abs(d).max())) ** 2)
        n = int(fitted.sum())
        return chi2(pred[fitted], d[fitted], np.sqrt(noise2[fitted]), SEARCH_MODEL_ERROR) > (
            chi2_limit(n)
        )

    def far_noise(self, fits: list[RoundFit], xy: NDArray, d: NDArray) -> float | None:
        """RMS residual [m] of the contacts ``fits`` over the taxels farther than REACH from
        each (at least FAR_TAXELS of them; else None): the readings' noise, measured where no
        contact is fitted (the residual there is not pulled down by the fit). Readings in
        counts (not ``precise``): at most ROBUST_CAP times the level the share of those taxels
        off by half a count or more gives (:func:`robust_scale`), precise readings at most
        ROBUST_CAP times their median absolute residual's, so that a second contact among them
        does not read as noise (it would then hide itself from the seeds)."""
        if len(fits) == 1:  # (the frame's usual case: the general search cost 3× more)
            dx, dy = xy[:, 0] - fits[0].center[0], xy[:, 1] - fits[0].center[1]
            far = dx * dx + dy * dy > REACH * REACH
        else:
            far = distance_to_points(xy, np.array([f.center for f in fits])) > REACH
        n = int(np.count_nonzero(far))
        if n < FAR_TAXELS:
            return None
        res = self.predicted(fits, xy[far]) - d[far]
        rms = math.sqrt(float(res @ res) / n)
        if self.precise:
            # At most ROBUST_CAP times the median absolute residual's σ (1.4826·MAD of
            # Gaussian noise): a second contact among those taxels must not read as noise.
            mad = float(np.partition(np.abs(res), n // 2)[n // 2])  # (the upper median)
            return min(rms, ROBUST_CAP * 1.4826 * mad)
        half = 0.5 * math.sqrt(6.0) * self.count_sigma  # half a count [m]
        return min(rms, ROBUST_CAP * robust_scale(res, half))

    def far_level(self, fit: RoundFit, xy: NDArray, d: NDArray) -> float | None:
        """The readings' noise [m] that separate contacts are weighed in, measured on the
        taxels farther than REACH from the single contact ``fit``: :meth:`far_noise`, but at
        most the RMS of the smallest four fifths of their residuals scaled to a Gaussian's σ
        (E[x² | |x| < q₀.₈] = 0.4377 σ²) — the other contacts, not fitted yet, read among
        those taxels (with the driver's baseline offsets, three contacts measured 1.67 σ
        where the readings held 1.3 σ, and hid each other)."""
        full = self.far_noise([fit], xy, d)
        if full is None:
            return None
        dx, dy = xy[:, 0] - fit.center[0], xy[:, 1] - fit.center[1]
        far = dx * dx + dy * dy > REACH * REACH
        res = np.abs(self.tables.predict(fit, xy[far]) - d[far])
        keep = np.partition(res, int(0.8 * len(res)) - 1)[: int(0.8 * len(res))]
        return min(full, math.sqrt(float(keep @ keep) / len(keep) / 0.4377))

    def _misfit(self, fit: RoundFit, xy: NDArray, d: NDArray) -> float:
        """Σ ((prediction − reading)/σ)² of ``fit`` over every taxel (σ: ``sigma``, or 1)."""
        res = self.tables.predict(fit, xy) - d
        return float(np.sum(np.square(res if self.sigma is None else res / self.sigma)))

    def starts(self, cop: NDArray | None, xy: NDArray, d: NDArray) -> NDArray[np.float64]:
        """(S, 2) centres [m] to search a single round contact around: ``cop`` (the detector's
        best place, or the grid solution's centre of pressure), the strongest taxel (when it
        reads above the contact threshold), the centroid of the readings above the threshold
        within START_REACH of it, and the centroid of the readings' magnitudes within
        MAGNITUDE_REACH of the largest, each kept when more than START_APART from those
        before.

        Why several: a broad flat contact reads as a ring of taxels around a quiet centre, and
        its detector place or grid support can sit on one side of the ring (a 6 mm punch over a
        taxel was fitted 2 mm off from there alone). Why the magnitudes: a small contact
        between taxels reads negative all round (no strongest taxel under it), and the bulge
        ring is centred on it. On 200 noise-free random presses (point taxels, their own
        tables) the magnitude centroid was within 2.9 mm of the centre, the detector's place up
        to 8.8 mm off; with it 4 fits ended in a false valley, without it 13. Its small
        readings count: weighting only those above the threshold lost most of the gain."""
        strongest = int(np.argmax(d))
        out = [] if cop is None else [np.asarray(cop, dtype=np.float64)]
        if d[strongest] > self.contact_threshold or cop is None:
            out.append(xy[strongest])
        off = xy - xy[strongest]
        up = (d > self.contact_threshold) & (np.hypot(off[:, 0], off[:, 1]) <= START_REACH)
        if up.any():
            out.append((d[up] @ xy[up]) / d[up].sum())
        size = np.abs(d)
        off = xy - xy[int(np.argmax(size))]
        around = np.hypot(off[:, 0], off[:, 1]) <= MAGNITUDE_REACH
        if size[around].sum() > 0:
            out.append((size[around] @ xy[around]) / size[around].sum())
        kept: list[NDArray] = []
        for c in out:
            if all(math.hypot(c[0] - k[0], c[1] - k[1]) > START_APART for k in kept):
                kept.append(c)
        return np.array(kept)

    def predicted(self, fits: list[RoundFit], xy: NDArray, skip: int = -1) -> NDArray[np.float64]:
        """Compressions [m] that the contacts ``fits`` (but number ``skip``) make at xy."""
        out = np.zeros(len(xy))
        for j, f in enumerate(fits):
            if j != skip:
                out += self.tables.predict(f, xy)
        return out

    def least_squares(self, seeds: list[NDArray], xy: NDArray, d: NDArray) -> list[RoundFit]:
        """Least-squares round contacts, one per seed, strongest first, each fitted to the
        readings minus the contacts already fitted; then each once more with all the others
        removed (the first was fitted with the others' readings still in the data)."""
        fits: list[RoundFit] = []
        for start in seeds:
            rest = d - self.predicted(fits, xy)
            fit = fit_round_contact(self.tables, xy, rest, start, polish=False)
            if fit is not None:
                fits.append(fit)
        for k in range(len(fits)):
            rest = d - self.predicted(fits, xy, skip=k)
            again = fit_round_contact(self.tables, xy, rest, fits[k].center, polish=False)
            if again is not None:
                fits[k] = again
        return fits

    def seeds(self, xy: NDArray, d: NDArray, level: float = 1.0) -> list[int]:
        """Taxels (indices into xy) where separate contacts may press, strongest first: those
        reading above CONTACT_SEED_LEVEL contact thresholds (times ``level`` ≥ 1, the
        readings' noise over the assumed one) that read most within CONTACT_SEPARATION of
        themselves (ties to the first) and are parted from every stronger one by a dip
        (:func:`dip_between`), at most ``max_contacts``."""
        seeds: list[int] = []
        for i in np.argsort(-d, kind="stable"):
            if d[i] <= CONTACT_SEED_LEVEL * max(level, 1.0) * self.contact_threshold:
                break
            if len(seeds) == self.max_contacts:
                break
            if all(
                np.hypot(*(xy[i] - xy[j])) >= CONTACT_SEPARATION and dip_between(xy, d, i, j)
                for j in seeds
            ):
                seeds.append(int(i))
        return seeds


_NEIGHBOURHOODS: dict[bytes, NDArray[np.float64]] = {}


def neighbourhood(xy: NDArray) -> NDArray[np.float64]:
    """(K, K) weights exp(−r²/2w²) of the taxels xy [m] (K, 2) on each other, w =
    RESIDUAL_WIDTH (kept for the last few taxel sets: a patch's frames use one or two)."""
    key = np.ascontiguousarray(xy, dtype=np.float64).tobytes()
    w = _NEIGHBOURHOODS.get(key)
    if w is None:
        dx = xy[:, 0, None] - xy[None, :, 0]
        dy = xy[:, 1, None] - xy[None, :, 1]
        w = np.exp(-(dx * dx + dy * dy) / (2.0 * RESIDUAL_WIDTH**2))
        if len(_NEIGHBOURHOODS) >= 8:
            _NEIGHBOURHOODS.pop(next(iter(_NEIGHBOURHOODS)))
        _NEIGHBOURHOODS[key] = w
    return w


def skin_hull(taxel_xy: NDArray) -> NDArray[np.float64] | None:
    """(H, 3) half-planes n·x + b ≤ 0 [m] of the convex hull of the taxel centres (K, 2) [m],
    or None when they span no area (fewer than three, or in a line)."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        return np.asarray(ConvexHull(np.asarray(taxel_xy, dtype=np.float64)).equations)
    except (QhullError, ValueError):
        return None


def on_skin(hull: NDArray | None, centre: tuple[float, float], margin: float = SKIN_MARGIN) -> bool:
    """Whether ``centre`` [m] lies within ``margin`` [m] of the taxel hull ``hull``
    (:func:`skin_hull`; None: anywhere)."""
    if hull is None:
        return True
    return bool(np.max(hull[:, :2] @ np.asarray(centre, dtype=np.float64) + hull[:, 2]) <= margin)


def chi2(pred: NDArray, d: NDArray, sigma: float | NDArray, model_error: float) -> float:
    """Σ (pred − d)²/(σ² + (e·pred)²): the misfit of predicted compressions ``pred`` [m] to the
    readings ``d`` [m] against their noise ``sigma`` [m] (scalar or per reading) and a
    relative model error ``model_error`` [-] of the prediction."""
    return float(np.sum((pred - d) ** 2 / (np.square(sigma) + (model_error * pred) ** 2)))


def chi2_limit(n: int) -> float:
    """The largest :func:`chi2` of ``n`` readings that a contact explains: n + 5·√(2n)."""
    return n + 5.0 * math.sqrt(2.0 * n)


def dip_between(xy: NDArray, d: NDArray, i: int, j: int) -> bool:
    """True unless the taxels between taxels i and j (within 4 mm of the middle 60 % of the
    segment joining them) all read at least half of the weaker of the two: a broad contact
    (a 12 mm punch reads alike under its whole face) is one contact, not two."""
    a, b = xy[i], xy[j]
    u = b - a
    t = (xy - a) @ u / (u @ u)
    off = np.abs((xy - a) @ np.array([-u[1], u[0]])) / math.hypot(*u)
    between = (t > 0.2) & (t < 0.8) & (off <= 4.0e-3)
    return not between.any() or float(d[between].min()) < 0.5 * min(float(d[i]), float(d[j]))


def spread(fits: list[RoundFit], distance: float) -> list[RoundFit]:
    """The contacts ``fits`` in order, but each within ``distance`` [m] of one kept before it."""
    kept: list[RoundFit] = []
    for f in fits:
        if all(
            math.hypot(f.center[0] - k.center[0], f.center[1] - k.center[1]) >= distance
            for k in kept
        ):
            kept.append(f)
    return kept


def apart(fits: list[RoundFit], distance: float) -> bool:
    """True when every two of the contacts ``fits`` are at least ``distance`` [m] apart."""
    c = np.array([f.center for f in fits])
    far = np.hypot(*(c[:, None, :] - c[None, :, :]).transpose(2, 0, 1))
    return bool(np.all(far[np.triu_indices(len(c), 1)] >= distance))
