"""The calibration's report in words: whether the fit is good, how sure its parameters are, and
what would improve it (the lines ``tactile-contact-calibrate`` prints, kept in the manifest).

Grades of the fit, from the relative residual ρ (RMS of predicted − measured over the RMS of
the readings): good ρ ≤ 10 % (named presses of the paper's protocol: 4 % at 1 % noise, 5–9 % in
8-bit counts), fair ≤ 25 %, poor beyond. A fit that barely improves on the layout's nominal
response (ρ > 0.8 × ρ_nominal while ρ is fair or poor) says the presses and the readings do not
match. No ROS import.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from tactile_contact.offline.calibrate import Calibration

#: Relative residual limits of a good and a fair fit [-].
GOOD, FAIR = 0.10, 0.25
#: Presses fewer than this: the report asks for more.
FEW_PRESSES = 24
#: A press whose relative residual is this many times the median is named.
OUTLIER = 3.0


#: A residual at most this many times the layout's noise model is the readings' own noise.
AT_NOISE = 1.25


def at_noise(cal: Calibration) -> bool:
    """Whether the fit leaves about the readings' own noise (then a high relative residual
    says the presses read little above it, not that they do not match their readings)."""
    return cal.noise > 0 and cal.residual <= AT_NOISE * cal.noise


def _noise_words(cal: Calibration) -> str:
    return (
        f"The fit leaves {cal.residual * 1e6:.1f} µm RMS, about the readings' own noise (the "
        f"layout's noise model: {cal.noise * 1e6:.1f} µm): the presses read too little above "
        "it to pin the response (a simulated session's 8-bit readings do, whatever the model). "
        "Press harder (1–3 N), or average each press over more frames: a rig's session holding "
        "each press still"
    )


def grade(cal: Calibration) -> str:
    """ "good", "fair" or "poor" (module docstring)."""
    rho = cal.relative_residual
    return "good" if rho <= GOOD else "fair" if rho <= FAIR else "poor"


def unidentified_message(cal: Calibration, limit: float) -> str:
    """Why the bundle is not written: what the presses cannot pin and what to add."""
    u = cal.uncertainty
    sf, sg = _force_sigma(u), u["sigma"]["gain"]
    a, b, c = _strongest(u)
    which = "the forces' scale" if cal.named else "each of them, with no indenter named"
    head = (
        f"the presses do not pin the taxel response: forces' scale ±{sf:.1%}, gain ±{sg:.1%} "
        f"(1 σ; at most ±{limit:.0%} is accepted for {which}); {a} and {b} trade against "
        f"each other (correlation {c:+.2f}); forces from such a bundle could be off by "
        f"{max(sf, sg):.0%} or more. "
    )
    if grade(cal) != "good" and at_noise(cal):
        why = _noise_words(cal)
    elif grade(cal) != "good" and cal.relative_residual > 0.8 * cal.nominal_relative_residual:
        why = (
            f"The fit leaves {cal.relative_residual:.0%} of the readings unexplained, about as "
            f"much as the nominal response ({cal.nominal_relative_residual:.0%}): the presses "
            "do not match their readings. Check that positions are in metres in the patch "
            "frame, forces in newtons from a zeroed sensor, readings in the bundle's taxel "
            "order, and that each press is one round contact"
        )
    elif not cal.named:
        amb = u.get("ambiguous")
        two = (
            ""
            if amb is None
            else (
                f"Two fits explain the readings about as well (gain {amb['gains'][0]:.3f} "
                f"leaving {amb['relative_residuals'][0]:.2%}, gain {amb['gains'][1]:.3f} "
                f"leaving {amb['relative_residuals'][1]:.2%}): the presses choose each "
                "contact's family and size differently in each, and cannot tell them apart. "
            )
        )
        why = two + (
            "The presses name no indenter, so each press's contact size is fitted as well and "
            "takes the place of the footprint radius and layer scale. Add an 'indenter' entry "
            "to the presses file naming each press's indenter ('sphere 12 mm', 'sphere 6 mm', "
            "'cylinder 12 mm', 'cylinder 3 mm', or 'hertz:R' / 'punch:a' with R, a in mm): "
            "a session pressed with one known sphere or cylinder needs only its name on every press"
        )
    else:
        why = (
            "Add presses: more of them (24–48), spread over the patch (over taxels and between "
            "them) and over 0.5–3 N, with more than one indenter size"
        )
    return (
        head + why + "; or pass --accept-uncertain to write the bundle anyway (its manifest "
        "keeps these uncertainties)."
    )


def _force_sigma(u: dict, named: bool = True) -> float:
    """The forces' 1-σ relative scale error (the gain's when the fit has none recorded);
    for presses without indenter names the larger of it and the gain's (Calibration.identified).
    """
    s = u.get("sigma", {})
    f = float(s.get("force_scale", s.get("gain", float("inf"))))
    return f if named else max(f, float(s.get("gain", float("inf"))))


def _strongest(u: dict) -> tuple[str, str, float]:
    names = ("gain", "footprint radius", "layer scale")
    c = np.asarray(u["correlation"]["matrix"])
    best = (names[0], names[2], 0.0)
    for i in range(3):
        for j in range(i + 1, 3):
            if abs(c[i, j]) > abs(best[2]):
                best = (names[i], names[j], float(c[i, j]))
    return best


def report(cal: Calibration, limit: float) -> list[str]:
    """Lines in words: the fit's grade, the parameters with their 1-σ errors, and what would
    improve the calibration."""
    g = grade(cal)
    rho, nom = cal.relative_residual, cal.nominal_relative_residual
    lines = []
    verdict = {
        "good": "good: the fitted response explains the readings to",
        "fair": "fair: the fitted response leaves",
        "poor": "poor: the fitted response leaves",
    }[g]
    tail = "of their RMS" if g == "good" else "of the readings unexplained"
    u = cal.uncertainty
    pinned = bool(u) and _force_sigma(u, cal.named) <= limit
    if not pinned:
        verdict = "NOT USABLE: the parameters are not identified; the response leaves"
        tail = "of the readings unexplained"
    lines.append(
        f"fit {verdict} {rho:.1%} {tail} (the layout's nominal response: {nom:.1%}; "
        f"{cal.presses} presses, {'named' if cal.named else 'no'} indenters)"
    )
    if u:
        s = u["sigma"]
        a, b, c = _strongest(u)
        lines.append(
            f"parameters (±1 σ from the fit's Jacobian): gain {cal.gain:.4f} ± {s['gain']:.4f}, "
            f"footprint radius {cal.footprint_radius * 1e3:.2f} ± "
            f"{s['footprint_radius'] * 1e3:.2f} mm, layer scale {cal.layer_scale:.3f} ± "
            f"{s['layer_scale']:.3f}; strongest correlation {a}–{b} {c:+.2f}; forces' scale "
            f"± {_force_sigma(u):.1%}"
        )
    improve = []
    if not pinned:
        improve.append(
            f"NOT IDENTIFIED (±{_force_sigma(u, cal.named):.1%} > ±{limit:.0%}): "
            + ("name each press's indenter" if not cal.named else "add presses")
        )
    if g != "good" and at_noise(cal):
        improve.append(_noise_words(cal)[0].lower() + _noise_words(cal)[1:])
    elif g != "good" and rho > 0.8 * nom:
        improve.append(
            "the fit barely improves on the nominal response: the presses' positions or forces "
            "do not match their readings: check that positions are in metres in the patch frame, "
            "forces in newtons from a zeroed sensor, readings in the bundle's taxel order, and "
            "that each press is one round contact"
        )
    elif g != "good":
        improve.append(
            "part of the readings is not explained: look at the presses named below, the "
            "indenter names, and noise (more frames averaged per press)"
        )
    bad = _outliers(cal)
    if bad:
        improve.append(
            "presses far worse than the rest (index: relative residual): "
            + ", ".join(f"{i}: {r:.0%}" for i, r in bad)
            + " — check their position, force and indenter, or whether they read little above "
            "the noise (light presses, few counts)"
        )
    edges = []
    grid = cal.grid or {}
    feet, scales = grid.get("footprints"), grid.get("layer_scales")
    if feet and cal.footprint_radius >= max(feet) - 1e-9:
        edges.append(f"footprint radius at its largest tried ({max(feet) * 1e3:.1f} mm)")
    if scales and (cal.layer_scale <= min(scales) + 1e-9 or cal.layer_scale >= max(scales) - 1e-9):
        edges.append(f"layer scale at an end of {min(scales):g}–{max(scales):g}")
    if edges:
        improve.append(
            "; ".join(edges) + ": the layout's elastomer (thickness, modulus) may be off"
        )
    if cal.presses < FEW_PRESSES:
        improve.append(
            f"{cal.presses} presses: {FEW_PRESSES}–48 would narrow the parameters' errors"
        )
    if improve:
        lines += ["to improve: " + s for s in improve]
    else:
        lines.append("nothing to improve: the presses pin the response (more would change little)")
    return lines


def _outliers(cal: Calibration) -> list[tuple[int, float]]:
    r = np.asarray(cal.press_residuals, dtype=np.float64)
    if r.size < 4:
        return []
    med = float(np.median(r))
    idx = np.nonzero(r > max(OUTLIER * med, FAIR))[0]
    worst = idx[np.argsort(-r[idx])][:5]
    return [(int(i), float(r[i])) for i in worst]
