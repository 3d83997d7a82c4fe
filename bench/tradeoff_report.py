"""tradeoff.md and tradeoff.png from the results of bench/tradeoff.py (also its ``--replot``).

The Pareto front is taken per noise level over (median online time, median error), once for the
force error and once for the CoP error. The target of issue 6 is force error ≤ 10 % and CoP
error ≤ 1 mm (medians) at ≤ 1 ms online per patch frame; when nothing meets it the table says
how far the closest configuration is, as max(force/10 %, CoP/1 mm, time/1 ms).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

TARGET = {"force_err_pct_median": 10.0, "cop_mm_median": 1.0, "online_ms_median": 1.0}
REALISTIC = "0.15 count +offsets"


def pareto(rows: list[dict[str, Any]], key: str) -> list[bool]:
    """Rows not dominated in (median online time, ``key``)."""
    t = "online_ms_median"
    return [
        not any(
            o[t] <= r[t] and o[key] <= r[key] and (o[t] < r[t] or o[key] < r[key]) for o in rows
        )
        for r in rows
    ]


def distance(r: dict[str, Any]) -> float:
    """How far from the target: 1 or less meets it (the worst of the three ratios)."""
    return max(r[k] / v for k, v in TARGET.items())


def _fmt(r: dict[str, Any], front: tuple[bool, bool]) -> str:
    mark = "F" * front[0] + "C" * front[1]
    return (
        f"| {r['key']} | {r['model']} | {r['cell_mm']:g} | {r['measurement']} | {r['solver']} | "
        f"{r['dtype']} | {r['build_s']:.2f} | {r['build_mb']:.0f} | "
        f"{r['online_ms_median']:.2f} ({r['online_ms_p99']:.2f}) | "
        f"{r['force_err_pct_median']:.1f} ({r['force_err_pct_p90']:.0f}) | "
        f"{r['cop_mm_median']:.2f} ({r['cop_mm_p90']:.1f}) | {r['iou_median']:.2f} | "
        f"{r['l2_traction_median']:.2f} | {r['l2_deflection_median']:.2f} | "
        f"{r['detected'] * 100:.0f} % | {mark} |"
    )


def table(results: dict[str, Any]) -> str:
    rows = results["rows"]
    noises = list(dict.fromkeys(r["noise"] for r in rows))
    pr = results["protocol"]
    head = [
        f"Cases per noise draw: {pr['cases']} = {len(pr['indenters'])} indenters × "
        f"{len(pr['positions'])} positions × {len(pr['modules'])} module(s) × "
        f"{len(pr['forces_N'])} forces ({', '.join(f'{f:g}' for f in pr['forces_N'])} N); "
        f"noisy levels repeated with {pr['repeats_noisy']} seeds. {results['machine']}; sweep "
        f"{results['seconds']:.0f} s. Errors: median (p90); undetected contacts count as 100 % "
        "force and 99 mm CoP error. Pareto column: F = on the force-error front, C = on the "
        "CoP front (per noise level). `+offsets`: a fixed per-taxel baseline offset of up to "
        "±½ count, as a real driver's baseline leaves.",
        "",
    ]
    cols = (
        "| key | model | cell mm | measurement | solver | dtype | build s | build MB | "
        "online ms med (p99) | force err % | CoP mm | IoU | L2 traction | L2 deflection | "
        "detected | Pareto |\n|" + "---|" * 16
    )
    out = head
    for noise in noises:
        sub = [r for r in rows if r["noise"] == noise]
        fronts = list(
            zip(pareto(sub, "force_err_pct_median"), pareto(sub, "cop_mm_median"), strict=True)
        )
        out += [f"## Noise: {noise}", "", cols]
        out += [_fmt(r, f) for r, f in zip(sub, fronts, strict=True)]
        met = [r["key"] for r in sub if distance(r) <= 1.0]
        best = min(sub, key=distance)
        out += [
            "",
            "Target (force ≤ 10 %, CoP ≤ 1 mm median, ≤ 1 ms online): "
            + (
                "met by " + ", ".join(met)
                if met
                else f"not met; closest {best['key']} at {distance(best):.1f}× "
                f"(force {best['force_err_pct_median']:.0f} %, CoP "
                f"{best['cop_mm_median']:.2f} mm, {best['online_ms_median']:.2f} ms)"
            ),
            "",
        ]
    names = {r["key"]: r["config"] for r in rows}
    out += ["## Configurations", ""] + [f"- `{k}`: {v}" for k, v in names.items()]
    return "\n".join(out) + "\n"


def render(results: dict[str, Any], out: Path) -> None:
    """Write ``out``/tradeoff.md and ``out``/tradeoff.png."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    (out / "tradeoff.md").write_text(table(results))
    rows = results["rows"]
    noises = list(dict.fromkeys(r["noise"] for r in rows))
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.5), layout="constrained")
    panels = (
        ("force_err_pct_median", "total force error, median [%]", 10.0),
        ("cop_mm_median", "CoP error, median [mm]", 1.0),
    )
    for ax, (key, label, target) in zip(axes, panels, strict=True):
        for k, noise in enumerate(noises):
            sub = [r for r in rows if r["noise"] == noise]
            front = pareto(sub, key)
            colour, marker = f"C{k}", "osD^v"[k % 5]
            for r, f in zip(sub, front, strict=True):
                ax.scatter(
                    r["online_ms_median"],
                    r[key],
                    marker=marker,
                    s=55 if f else 18,
                    c=colour if f else "lightgrey",
                    edgecolors="k" if f else "none",
                    zorder=3 if f else 2,
                )
                if f and noise in (REALISTIC, noises[0]):
                    ax.annotate(
                        r["key"],
                        (r["online_ms_median"], r[key]),
                        fontsize=6,
                        xytext=(3, 3),
                        textcoords="offset points",
                    )
            pts = sorted(
                (r["online_ms_median"], r[key]) for r, f in zip(sub, front, strict=True) if f
            )
            ax.step(
                *zip(*pts, strict=True),
                where="post",
                c=colour,
                lw=1,
                label=f"Pareto front, noise {noise}",
            )
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("online time per patch frame, median [ms]")
        ax.set_ylabel(label)
        ax.axvline(1.0, c="grey", ls=":", lw=1)
        ax.axhline(target, c="grey", ls=":", lw=1)
        xs = [r["online_ms_median"] for r in rows]
        ys = [r[key] for r in rows]
        x0, y0 = min(min(xs), 1.0) / 1.5, min(min(ys), target) / 1.5
        ax.set_xlim(x0, max(xs) * 1.5)
        ax.set_ylim(y0, max(ys) * 1.5)
        ax.fill_between([x0, 1.0], y0, target, color="g", alpha=0.1, label="target region")
        ax.legend(fontsize=7)
    fig.suptitle(
        "tactile_contact: online time against error (large: Pareto front of its "
        "noise level, labelled for no noise and realistic noise; grey: dominated)",
        fontsize=10,
    )
    fig.savefig(out / "tradeoff.png", dpi=90)
    plt.close(fig)
