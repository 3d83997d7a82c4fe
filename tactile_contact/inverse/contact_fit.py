"""Stage 3 of a frame: round contacts fitted straight to the readings, followed frame to frame.

One, or up to ``max_contacts`` separate, round contacts (punch- or Hertz-like, centre, radius,
force) are fitted to the readings through the radial responses tabulated at build time
(:class:`tactile_contact.inverse.contacts.ContactFitter`, a compiled multi-start least-squares
search from the detector's best place). They are kept when they explain the readings to within
noise and model error (a χ² test on the least-squares fit); quantised readings (whole 8-bit
counts) then report the posterior mean over the contact's size/centre/force valley instead of
the least-squares point.

*Following* (:class:`Followed`): a single contact found in the last frame is refitted alone
from where it was, and the search runs only when that fit explains the readings clearly worse
than the last search did. The state (the contact followed) is the caller's: it passes the last
frame's and gets this frame's back. No ROS import.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from tactile_contact.inverse.contacts import (
    ContactFitter,
    chi2,
    chi2_limit,
    on_skin,
    skin_hull,
)
from tactile_contact.inverse.readings import Frame
from tactile_contact.inverse.reductions import median, norm
from tactile_contact.inverse.round_contact import (
    RoundFit,
    RoundTables,
    follow_round_contact,
    posterior_contact,
    rescan_round_contact,
)

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
#: A single contact searched in precise readings and fitted at least this broad [m], punch
#: or sphere, is searched again from its centre (round_contact.rescan_round_contact): a broad
#: punch and a broad sphere read alike, and the search ended on the punch where the sphere
#: explained the readings better (bench_robust, full protocol, point truth, calibrated, 1 %
#: noise: a 12 mm sphere between three taxels at 1.8 N, −34.5 %); a sphere's radius–force
#: valley is as flat (noise-free 6 mm spheres at 1–2 N fitted as 2.8–3.6 mm spheres, −6 …
#: −9 %, 0.003–0.006 σ² above the true contact's valley; bench_valleys, 1600 presses: 6 off
#: from 3 mm compared over every taxel, 4 over the near ones, 0 from 2 mm). Only there: on
#: every frame the rescan cost 14 % of a float contact frame; from 2 mm (161 of 240 float
#: presses, 1 % noise, 0.2–3 N) against 3 mm (92) it costs CPU p50 × 1.05, p90 × 1.08, mean
#: × 0.96, the same errors. Quantised readings are left alone: their posterior spans both
#: families.
RESCAN_BROAD = 2.0e-3
#: ... and compared with it over the taxels within this distance of its centre [m] (the
#: search's ``near``): beyond, the tables' reach and the bulge's tail differ by more than
#: the two ends of a flat valley do (a 1.50 N 6 mm sphere: over every taxel the rescanned,
#: true contact misfit 0.0003 σ² more than the −7 % one, and was not kept).
RESCAN_NEAR = 0.015
#: Relative model error [-] the χ² test allows on top of the noise (the tables against a
#: finer forward model: 1–4 %).
ROUND_MODEL_ERROR = 0.05
#: The posterior over the mean of n frames of a held scene assumes that mean's noise
#: (σ/√n), but at least this share of one count/√6: with little converter noise (≲ 0.3
#: count) the rounding is not dithered and each taxel keeps an error averaging cannot remove.
#: (Held presses, point-taxel truth, calibrated, 10 frames, ≥ 1 N: 0.15-count noise 8.4 %
#: without the floor, 8.3 % with it, 7.0 % at one count/√6 — which at 0.5-count noise gave
#: 4.6 % against 4.5 %, and 0.5 N 11.8 against 9.5 %.)
FUSED_POSTERIOR_FLOOR = 1.0 / 3.0
#: The posterior's prior over the contact radius blends from weights ∝ a to uniform in log a
#: (round_contact.posterior_contact's ``log_prior`` t) with the readings' noise σ as the
#: stage knows it (the caller's, or the far taxels' measured RMS where above the model's):
#: t = clip((σ/σ_q − LOG_PRIOR_FROM)/LOG_PRIOR_SPAN, 0, 1), σ_q = one count/√6, the
#: rounding's own error. Where the readings are no noisier than the driver hands them on,
#: the prior ∝ a stays, bit for bit: 0.15-count readings (the bag, bench_icub) measure
#: 0.03 count far, σ stays the model's σ_q (σ/σ_q = 1); the driver's readings (0.3 count of
#: noise and 0.3 of baseline offset, bench_icub "driver readings") measure σ/σ_q 1.29
#: median, 1.57 at most, and log a made them worse there (forearm single contacts median
#: 9.4 → 14.8 %). Beyond, noise widens the likelihood and the prior decides over a light
#: press's valley: it must not favour broad contacts (8-bit at 1 count, σ/σ_q ≈ 2.55: the
#: worst press 2.49 → 1.73× its force; docs/reconstruction.md). Full from 2.1 σ_q (≈ 0.8
#: count of converter noise); linear between so that no noise level flips the output.
LOG_PRIOR_FROM = 1.6
LOG_PRIOR_SPAN = 0.5


def log_prior_blend(noise: float, count_sigma: float) -> float:
    """The posterior's ``log_prior`` t in [0, 1] for readings of noise ``noise`` [m] whose
    rounding error is ``count_sigma`` [m] (one count/√6): 0 up to LOG_PRIOR_FROM σ_q, 1 from
    LOG_PRIOR_FROM + LOG_PRIOR_SPAN, linear between."""
    t = (noise / count_sigma - LOG_PRIOR_FROM) / LOG_PRIOR_SPAN
    return float(min(max(t, 0.0), 1.0))


@dataclass(frozen=True)
class Followed:
    """A single contact followed from frame to frame.

    Attributes:
        fit: its least-squares fit in the last frame.
        misfit: :func:`tactile_contact.inverse.contacts.chi2` of the fit that the last full
            search found; a followed fit may exceed it by FOLLOW_SLACK + FOLLOW_SLACK_SHARE of
            it.
        age: frames followed since that search.
        noise: the readings' noise [m] that search assigned them (the caller's, or measured
            at the far taxels); followed frames of readings whose noise was not passed blend
            the posterior's radius prior by it too (:func:`log_prior_blend`), so that the
            prior does not change between searched and followed frames of one press.
    """

    fit: RoundFit
    misfit: float
    age: int
    noise: float = 0.0

    @property
    def current(self) -> bool:
        """Young enough to be followed (FOLLOW_FRAMES)."""
        return self.age < FOLLOW_FRAMES


@dataclass(frozen=True)
class RoundContacts:
    """The stage's result.

    Attributes:
        fits: the contacts (posterior means for quantised readings).
        residual: ‖prediction − readings‖ [m] over the taxels used, of the contacts reported.
        followed: the contact to follow in the next frame (a single least-squares contact),
            or None.
    """

    fits: list[RoundFit]
    residual: float
    followed: Followed | None


class _FrameFitter(ContactFitter):
    """A ContactFitter for one frame that remembers its last :meth:`far_noise`: the search
    measures the noise its single contact leaves (when the caller passed none) and the stage
    then measures it again for the contacts it reports, most often that same single contact
    on the same readings (≈ 50 µs a forearm frame for nothing)."""

    def far_noise(self, fits: list[RoundFit], xy: NDArray, d: NDArray) -> float | None:
        last = self.__dict__.get("_last_far")
        if (
            last is not None
            and last[1] is xy
            and last[2] is d
            and len(last[0]) == len(fits)
            and all(a is b for a, b in zip(last[0], fits, strict=True))
        ):
            return last[3]
        far = super().far_noise(fits, xy, d)
        # (a frozen dataclass: the memo is set past its __setattr__)
        object.__setattr__(self, "_last_far", (list(fits), xy, d, far))
        return far


class ContactFit:
    """Round contacts of one patch's frames (see module docstring).

    Args:
        tables: the bundle's radial responses.
        taxel_xy: (K, 2) taxel centres [m].
        count_sigma: one count's compression [m] over √6 (the posterior's error, and the
            unit of the multi-contact evidence).
        contact_threshold: compression [m] above which a taxel reads contact.
        max_contacts: separate contacts fitted at most.
    """

    def __init__(
        self,
        tables: RoundTables,
        taxel_xy: NDArray[np.float64],
        count_sigma: float,
        contact_threshold: float,
        max_contacts: int,
    ) -> None:
        self.tables = tables
        self.taxel_xy = taxel_xy
        self.count_sigma = count_sigma
        self.contact_threshold = contact_threshold
        self.max_contacts = max_contacts
        self._skin = skin_hull(taxel_xy)

    def fit(
        self, frame: Frame, start: NDArray | None, previous: Followed | None
    ) -> RoundContacts | None:
        """The frame's round contacts, or None when they do not explain the readings (χ²).

        With ``previous`` (the contact followed), its refit alone is tried first and kept
        when its χ² is within the test and within the slack of the last search's; otherwise
        (or without ``previous``) the multi-start search runs from ``start`` [m] (the
        detector's best place). ``start`` None: following only, no search.
        """
        ok = frame.ok
        xy, d, s = self.taxel_xy[ok], frame.delta[ok], frame.sigma[ok]
        if frame.frames != 1:  # the mean of a held scene's frames: that mean's noise
            s = s / np.sqrt(frame.frames)
        limit = chi2_limit(len(d))
        fits, followed = None, None
        # Readings whose noise the caller did not pass: the fit measures it too, in counts or
        # precise (float readings with 1 % of their peak as noise, a 3 N press: 6.6 µm
        # against the assumed 4.3, failed the χ² test and took the grid path, 30-45 % off
        # where the fit was 7 %, or won a second contact made of noise 19 mm away; issue 26).
        estimate = frame.estimate and frame.frames == 1
        # The posterior's error: the rounding's (one count/√6), not a learnt noise level; the
        # mean of a held scene's frames, that mean's noise; readings noisier than assumed,
        # their own (below).
        post = self.count_sigma
        if frame.frames != 1:
            post = max(median(s), FUSED_POSTERIOR_FLOOR * self.count_sigma)
        if previous is not None:
            # The posterior spans both families anyway: only the followed one is fitted.
            single = follow_round_contact(
                self.tables, xy, d, previous.fit, sigma=s, other_family=not frame.quantised
            )
            if single is not None:
                pred = self.tables.predict(single, xy)
                misfit = chi2(pred, d, s, ROUND_MODEL_ERROR)
                slack = FOLLOW_SLACK + FOLLOW_SLACK_SHARE * previous.misfit
                if misfit <= min(limit, previous.misfit + slack):
                    fits = [single]
                    followed = Followed(single, previous.misfit, previous.age + 1, previous.noise)
        fitter = _FrameFitter(
            self.tables,
            self.count_sigma,
            self.contact_threshold,
            s,
            self.max_contacts,
            precise=frame.scale_free,
            estimate_noise=estimate,
        )
        if fits is None:
            if start is None:
                return None
            found = fitter.fit(xy, d, np.asarray(start, dtype=np.float64))
            if found is None or not all(on_skin(self._skin, f.center) for f in found[0]):
                return None
            fits = found[0]
            if frame.scale_free and len(fits) == 1:
                fits = [self._rescan(fits[0], xy, d, s)]
            pred = fitter.predicted(fits, xy)
            if estimate:
                # No noise level passed: the readings' own, as the taxels beyond the contacts
                # read it, where larger than assumed (the χ² test and the posterior's width).
                far = fitter.far_noise(fits, xy, d)
                if far is not None and far > float(np.max(s)):
                    s, post = np.maximum(s, far), max(post, far)
            misfit = chi2(pred, d, s, ROUND_MODEL_ERROR)
            if misfit > limit:
                return None
            if len(fits) == 1:
                followed = Followed(fits[0], misfit, 0, median(s))
        # The test above is on the least-squares fit (the least χ² the model reaches), not on
        # the posterior mean: the mean of a curved valley lies off its floor, and on the load
        # bench's 12 mm sphere it missed the test by a few percent where the fit passed it
        # (χ² 138 against 86, limit 132), sending good frames to the slower grid path.
        if frame.quantised and len(fits) == 1:
            # Quantised readings: report the posterior mean over the size/centre/force valley
            # (round_contact.posterior_contact) instead of the least-squares point. Its error is
            # the rounding's (one count/√6), not the learnt noise level: unless the contact is
            # followed, the same readings give the same contact whatever frames came before.
            noise = median(s)
            if estimate and followed is not None and followed.age > 0:
                # A followed frame does not measure the noise again: the last search's.
                noise = max(noise, followed.noise)
                post = max(post, followed.noise)
            t = log_prior_blend(noise, self.count_sigma)
            fits = [posterior_contact(self.tables, xy, d, fits[0], post, log_prior=t)]
            pred = fitter.predicted(fits, xy)
        return RoundContacts(fits, norm(pred - d), followed)

    def _rescan(self, fit: RoundFit, xy: NDArray, d: NDArray, s: NDArray) -> RoundFit:
        """``fit``, or the contact rescanned from its centre when ``fit`` is at least
        RESCAN_BROAD broad and the rescan, on the skin, explains the readings d [m] at xy [m]
        within RESCAN_NEAR of its centre better (Σ ((prediction − d)/s)², s [m] the readings'
        noise)."""
        if fit.radius < RESCAN_BROAD:
            return fit
        again = rescan_round_contact(self.tables, xy, d, fit, sigma=s)
        if again is None or not on_skin(self._skin, again.center):
            return fit

        near = np.hypot(*(xy - np.asarray(fit.center)).T) <= RESCAN_NEAR

        def misfit(f: RoundFit) -> float:
            e = (self.tables.predict(f, xy[near]) - d[near]) / s[near]
            return float(np.sum(e * e))

        return again if misfit(again) < misfit(fit) else fit

    def predicted(self, fits: list[RoundFit], ok: NDArray) -> NDArray[np.float64]:
        """(K,) compressions [m] of the contacts ``fits``, 0 at the taxels not ``ok``."""
        predicted = np.zeros(len(self.taxel_xy))
        for contact in fits:
            predicted += self.tables.predict(contact, self.taxel_xy)
        predicted[~ok] = 0.0
        return predicted
