"""Round contacts of one frame: one, or several separate ones, fitted to the taxel readings.

The reconstructor's default refinement (``refine: round``). Each contact is a round contact
of :mod:`tactile_contact.inverse.round_contact` (family, radius, force, centre), reported by its
posterior mean. Several are fitted only where the readings call for them: taxels reading well
above the contact threshold, far apart and parted by a dip in the readings between them seed
one contact each, and the separate contacts replace the single one only if they explain the
readings better by more than the extra parameters fitted to noise would.

All lengths in metres, forces in newtons, readings as compressions δ [m]. No ROS import.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from tactile_contact.inverse.round_contact import RoundFit, RoundTables, fit_round_contact

#: Taxels closer than this [m] seed one contact between them: the 5.5 mm taxel pitch cannot
#: tell two contacts that close apart.
CONTACT_SEPARATION = 8.0e-3
#: A taxel seeds a separate contact only above this many contact thresholds (≈ 2.6 counts):
#: through the driver an idle taxel reads up to about 1.7 counts (its baseline offset, the
#: converter noise), and seeding there split one pressed sphere into three contacts.
CONTACT_SEED_LEVEL = 2.5
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


@dataclass(frozen=True)
class ContactFitter:
    """Fits the round contacts of one frame.

    Attributes:
        tables: the bundle's radial responses.
        count_sigma: rounding error [m] of one reading (one count/√6 through the sensor
            model: a reading and its baseline, each rounded to a count); the unit of
            MULTI_CONTACT_EVIDENCE.
        contact_threshold: compression [m] above which a taxel reads contact.
        sigma: per-taxel error [m] the posterior assumes, or None to report least-squares
            points.
        max_contacts: separate contacts fitted at most.
    """

    tables: RoundTables
    count_sigma: float
    contact_threshold: float
    sigma: float | None = None
    max_contacts: int = 3

    def fit(
        self, xy: NDArray, d: NDArray, cop: NDArray | None
    ) -> tuple[list[RoundFit], float] | None:
        """(contacts, residual [m] of the least-squares points) for readings d [m] at taxels
        xy [m], searched around ``cop`` (the grid solution's centre of pressure, or None), or
        None when no round contact has a positive force."""
        start = self.starts(cop, xy, d)
        single = fit_round_contact(self.tables, xy, d, start, sigma=self.sigma)
        fits = [single] if single is not None else []
        residual = single.residual if single is not None else math.inf
        # Separate contacts must lower the squared residual by the evidence margin: a single
        # contact already within it leaves nothing to win (and skips 4-5 more fits).
        margin = MULTI_CONTACT_EVIDENCE * self.count_sigma**2
        seeds = [xy[i] for i in self.seeds(xy, d)] if residual**2 > margin else []
        if len(seeds) > 1:
            # Model choice on least-squares points (their residuals are those of the
            # predictions subtracted); the posterior then reports each contact.
            points = self.least_squares(seeds, xy, d)
            if len(points) > 1 and apart(points, CONTACT_SEPARATION):
                r_multi = float(np.linalg.norm(d - self.predicted(points, xy)))
                r_one = residual
                if r_one**2 - r_multi**2 > margin:
                    # The unweighted single fit may explain more than the weighted one.
                    one = fit_round_contact(self.tables, xy, d, start, polish=False)
                    r_one = min(one.residual if one is not None else math.inf, residual)
                if r_one**2 - r_multi**2 > margin:
                    fits, residual = [], r_multi
                    for k, f in enumerate(points):
                        rest = d - self.predicted(points, xy, skip=k)
                        post = fit_round_contact(self.tables, xy, rest, f.center, sigma=self.sigma)
                        fits.append(post if post is not None else f)
        return (fits, residual) if fits else None

    def starts(self, cop: NDArray | None, xy: NDArray, d: NDArray) -> NDArray[np.float64]:
        """(S, 2) centres [m] to search a single round contact around: ``cop`` (the detector's
        best place, or the grid solution's centre of pressure), the strongest taxel, and the
        centroid of the readings above the contact threshold within START_REACH of it, each
        kept when more than START_APART from those before. A broad flat contact reads as a ring
        of taxels around a quiet centre: its detector place or grid support can sit on one side
        of the ring, and a 6 mm punch over a taxel was fitted 2 mm off from there alone."""
        strongest = int(np.argmax(d))
        out = [] if cop is None else [np.asarray(cop, dtype=np.float64)]
        out.append(xy[strongest])
        off = xy - xy[strongest]
        up = (d > self.contact_threshold) & (np.hypot(off[:, 0], off[:, 1]) <= START_REACH)
        if up.any():
            out.append((d[up] @ xy[up]) / d[up].sum())
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

    def seeds(self, xy: NDArray, d: NDArray) -> list[int]:
        """Taxels (indices into xy) where separate contacts may press, strongest first: those
        reading above CONTACT_SEED_LEVEL contact thresholds that read most within
        CONTACT_SEPARATION of themselves (ties to the first) and are parted from every
        stronger one by a dip (:func:`dip_between`), at most ``max_contacts``."""
        seeds: list[int] = []
        for i in np.argsort(-d, kind="stable"):
            if d[i] <= CONTACT_SEED_LEVEL * self.contact_threshold:
                break
            if len(seeds) == self.max_contacts:
                break
            if all(
                np.hypot(*(xy[i] - xy[j])) >= CONTACT_SEPARATION and dip_between(xy, d, i, j)
                for j in seeds
            ):
                seeds.append(int(i))
        return seeds


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


def apart(fits: list[RoundFit], distance: float) -> bool:
    """True when every two of the contacts ``fits`` are at least ``distance`` [m] apart."""
    c = np.array([f.center for f in fits])
    far = np.hypot(*(c[:, None, :] - c[None, :, :]).transpose(2, 0, 1))
    return bool(np.all(far[np.triu_indices(len(c), 1)] >= distance))
