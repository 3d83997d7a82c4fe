"""``make demo``: the whole pipeline on the default patch, with no hardware.

A simulated indenter sweeps across the hexagon patch; the simulator writes module frames to a
python-can virtual bus, ``skin_driver`` decodes them and publishes ΔC, and
``contact_reconstruction`` publishes traction, deflection and the contact summary, all over
real DDS in one process. An observer node compares every summary with the simulator's truth,
prints latency and force / centre-of-pressure errors, and draws ``demo.png``.

The demo's bundle is the default one, not calibrated, and the driver's readings are 8-bit:
its force error is that of an uncalibrated skin (README: "Defaults, accuracy and speed"), and it
says so beside the figures a calibrated skin reaches. Frames whose press the reconstruction did
not report are shown as such (on the force plot and the centre-of-pressure path) with how far
the press was from the nearest taxel: a press between three taxels, ≈ 4 mm from each, reads
below one count at every one of them (docs/reconstruction.md), a gap in the skin.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

# Unloaded time before the sweep: the driver calibrates its baseline on it.
START_DELAY_S = 1.0
#: What a calibrated skin reaches (README, docs/bench/robust.md: median force error at ≥ 1 N),
#: printed beside the demo's uncalibrated figure.
CALIBRATED_FLOAT_PERCENT, CALIBRATED_8BIT_PERCENT, UNCALIBRATED_WORST_PERCENT = 2.3, 9.2, 15.8
#: The package's config/hexagon_patch.yaml (the source tree's: ros/ is two levels below it).
DEFAULT_LAYOUT = Path(__file__).resolve().parents[2] / "config" / "hexagon_patch.yaml"


@dataclass
class Observed:
    """What the observer node received (header stamps in seconds as keys)."""

    contact: dict[float, object] = field(default_factory=dict)
    truth: dict[float, object] = field(default_factory=dict)
    traction: dict[float, np.ndarray] = field(default_factory=dict)
    deflection: dict[float, np.ndarray] = field(default_factory=dict)
    taxels: dict[float, np.ndarray] = field(default_factory=dict)
    geometry: dict[str, object] = field(default_factory=dict)


@dataclass
class DemoReport:
    """Per matched frame: stamp [s], true and estimated force [N] and CoP [m], latency [s]."""

    stamps: np.ndarray
    force_true: np.ndarray
    force_est: np.ndarray
    cop_true: np.ndarray
    cop_est: np.ndarray
    latency: np.ndarray
    frames_published: int
    frames_simulated: int
    #: per frame: whether the reconstruction reported a contact
    in_contact: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    #: per frame: distance [m] from the true centre of pressure to the nearest taxel (NaN:
    #: not known)
    taxel_distance: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def loaded(self, min_force: float = 0.1) -> np.ndarray:
        """Frames whose true force is at least ``min_force`` [N]."""
        return self.force_true >= min_force

    def missed(self, min_force: float = 0.1) -> np.ndarray:
        """Frames with a true force of at least ``min_force`` [N] reported without contact."""
        if self.in_contact.size != self.stamps.size:
            return np.zeros(self.stamps.size, bool)
        return self.loaded(min_force) & ~self.in_contact

    def seen(self) -> np.ndarray:
        """Frames with a reported contact (those whose estimated CoP means something)."""
        if self.in_contact.size != self.stamps.size:
            return self.force_est > 0
        return self.in_contact

    def force_error(self) -> np.ndarray:
        """|F_est − F_true| / F_true on loaded frames."""
        m = self.loaded()
        return np.abs(self.force_est[m] - self.force_true[m]) / self.force_true[m]

    def cop_error(self) -> np.ndarray:
        """CoP distance [m] on loaded frames."""
        m = self.loaded()
        return np.linalg.norm(self.cop_est[m] - self.cop_true[m], axis=1)

    def frame_lines(self, every: int = 10) -> list[str]:
        """Every ``every``-th matched frame: time, true and estimated force, CoP error, latency."""
        lines = ["    t [s]  F true [N]  F est [N]  CoP err [mm]  latency [ms]"]
        t0 = self.stamps[0] if self.stamps.size else 0.0
        for j in range(0, self.stamps.size, every):
            cop = np.linalg.norm(self.cop_est[j] - self.cop_true[j]) * 1e3
            cop_text = f"{cop:12.2f}" if self.force_true[j] > 0 else f"{'-':>12s}"
            lines.append(
                f"{self.stamps[j] - t0:9.2f} {self.force_true[j]:11.2f} {self.force_est[j]:10.2f} "
                f"{cop_text}  {self.latency[j] * 1e3:12.2f}"
            )
        return lines

    def summary_lines(self) -> list[str]:
        lat = self.latency * 1e3
        fe = self.force_error() * 100
        ce = self.cop_error() * 1e3
        lines = [
            f"frames: {self.frames_published} summaries for {self.frames_simulated} "
            f"simulated periods ({self.loaded().sum()} with force ≥ 0.1 N)",
        ]
        if not lat.size:
            # Nothing to take a median of: say so (the node's log above says why) instead of
            # raising on an empty array after the whole run.
            return [*lines, "no contact summary arrived: no latency or error to report"]
        lines.append(
            f"latency CAN receive → summary published [ms]: median {np.median(lat):.2f}, "
            f"p99 {np.percentile(lat, 99):.2f}, max {lat.max():.2f}"
        )
        if fe.size:
            seen = self.seen()[self.loaded()]
            lines += [
                f"total force error [%]: median {np.median(fe):.1f}, "
                f"p90 {np.percentile(fe, 90):.1f} (frames reported without contact count 100 %)",
                "  uncalibrated: the default bundle's 2 mm-electrode response and the driver's "
                "8-bit readings;",
                f"  a calibrated skin: median {CALIBRATED_FLOAT_PERCENT} % (float readings), "
                f"{CALIBRATED_8BIT_PERCENT} % (8-bit) at >= 1 N, uncalibrated worst "
                f"{UNCALIBRATED_WORST_PERCENT} % (README, docs/bench/robust.md)",
                f"centre of pressure error [mm]: median {np.median(ce[seen]):.2f}, "
                f"p90 {np.percentile(ce[seen], 90):.2f} (frames with a contact reported)"
                if seen.any()
                else "centre of pressure error: no frame with a contact reported",
            ]
        missed = self.missed()
        if missed.any():
            full = missed & (self.force_true >= 0.9 * self.force_true.max())
            far = self.taxel_distance[full] * 1e3
            text = f"not seen: {int(missed.sum())} frames with force >= 0.1 N reported no contact"
            if full.any() and np.isfinite(far).any():
                text += (
                    f"; {int(full.sum())} of them at full force, {np.nanmin(far):.1f}-"
                    f"{np.nanmax(far):.1f} mm from the nearest taxel (between three taxels, where "
                    "a press reads about one count at each: a gap in the skin)"
                )
            lines.append(text)
        return lines


def _stamp(header: object) -> float:
    return round(header.stamp.sec + header.stamp.nanosec * 1e-9, 6)  # type: ignore[attr-defined]


def observer_node(context: object, patch: str, seen: Observed) -> object:
    """A node that subscribes to every output (so every output is computed) and stores it."""
    from rclpy.node import Node
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image

    from tactile_contact.msg import ContactState, GridGeometry, TaxelArray
    from tactile_contact.ros.common import STATIC_QOS

    qos = QoSProfile(depth=50, reliability=ReliabilityPolicy.BEST_EFFORT)
    node = Node("demo_observer", context=context)

    def image(store: dict) -> object:
        def cb(msg: Image) -> None:
            store[_stamp(msg.header)] = np.frombuffer(msg.data, "<f4").reshape(
                msg.height, msg.width
            )

        return cb

    node.create_subscription(
        ContactState,
        f"{patch}/contact",
        lambda m: seen.contact.__setitem__(_stamp(m.header), m),
        qos,
    )
    node.create_subscription(
        ContactState,
        f"{patch}/contact_truth",
        lambda m: seen.truth.__setitem__(_stamp(m.header), m),
        qos,
    )
    node.create_subscription(Image, f"{patch}/traction", image(seen.traction), qos)
    node.create_subscription(Image, f"{patch}/deflection", image(seen.deflection), qos)
    node.create_subscription(
        TaxelArray,
        f"{patch}/taxels",
        lambda m: seen.taxels.__setitem__(_stamp(m.header), np.asarray(m.delta_c, float)),
        qos,
    )
    for kind in ("traction", "deflection"):
        node.create_subscription(
            GridGeometry,
            f"{patch}/{kind}_geometry",
            lambda m, k=kind: seen.geometry.__setitem__(k, m),
            STATIC_QOS,
        )
    return node


def match(seen: Observed, tolerance: float, taxel_xy: np.ndarray | None = None) -> DemoReport:
    """Pair each summary with the truth of the nearest stamp (within ``tolerance`` [s]);
    ``taxel_xy`` (K, 2) [m] gives each frame's distance from the true CoP to a taxel."""
    truth_t = np.array(sorted(seen.truth))
    rows = []
    for t, est in sorted(seen.contact.items()):
        if truth_t.size == 0:
            break
        j = int(np.argmin(np.abs(truth_t - t)))
        if abs(truth_t[j] - t) > tolerance:
            continue
        tru = seen.truth[float(truth_t[j])]
        rows.append(
            (
                t,
                tru.total_force,
                est.total_force,
                (tru.center_of_pressure.x, tru.center_of_pressure.y),
                (est.center_of_pressure.x, est.center_of_pressure.y),
                est.latency,
                bool(est.in_contact),
            )
        )
    cols = list(zip(*rows, strict=True)) if rows else [[]] * 7
    cop_true = np.asarray(cols[3], float).reshape(-1, 2)
    if taxel_xy is None:
        distance = np.full(len(cop_true), np.nan)
    else:
        xy = np.asarray(taxel_xy, float)
        distance = np.hypot(
            cop_true[:, None, 0] - xy[None, :, 0], cop_true[:, None, 1] - xy[None, :, 1]
        ).min(axis=1, initial=np.inf)
    return DemoReport(
        stamps=np.asarray(cols[0], float),
        force_true=np.asarray(cols[1], float),
        force_est=np.asarray(cols[2], float),
        cop_true=cop_true,
        cop_est=np.asarray(cols[4], float).reshape(-1, 2),
        latency=np.asarray(cols[5], float),
        frames_published=len(seen.contact),
        frames_simulated=len(seen.truth),
        in_contact=np.asarray(cols[6], bool),
        taxel_distance=distance,
    )


def run(
    layout: Path, bundles: Path, duration: float, period_ms: int, scenario: str = "sweep"
) -> tuple[DemoReport, Observed, str]:
    """Run the graph for ``duration`` seconds; return the matched report and raw observations."""
    import rclpy
    from rclpy.context import Context

    from tactile_contact.model.layout import load_layout
    from tactile_contact.ros.bringup import GraphConfig, running_graph

    patch_layout = load_layout(layout).patches[0]
    patch = patch_layout.name
    config = GraphConfig(
        layout=str(layout),
        bundles_dir=str(bundles),
        channel=f"tactile_demo_{time.monotonic_ns()}",
        scenario=scenario,
        simulator={
            "period_ms": period_ms,
            "cycle_s": duration,
            "loop": False,
            # 0.15 count RMS after the shift: the noise of the accuracy study
            # (docs/reconstruction.md).
            "noise_cdc": 0.6,
            # ±½ count rest offsets, as an imperfectly calibrated module has.
            "rest_spread_cdc": 2.0,
            "start_delay_s": START_DELAY_S,
        },
    )
    seen = Observed()
    context = Context()
    rclpy.init(context=context)
    try:
        observer = observer_node(context, patch, seen)
        with running_graph(config, context, extra_nodes=(observer,)) as executor:
            end = time.monotonic() + START_DELAY_S + duration + 0.5
            while time.monotonic() < end:
                executor.spin_once(timeout_sec=0.02)
        observer.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
    report = match(seen, 0.5 * period_ms * 1e-3, patch_layout.taxel_xy())
    return report, seen, patch


def _extent(geom: object, shape: tuple[int, int]) -> list[float]:
    if geom is None:
        return [0, shape[1], 0, shape[0]]
    x0, y0 = geom.origin_x, geom.origin_y
    return [
        x0 * 1e3,
        (x0 + geom.width * geom.cell_size_x) * 1e3,
        y0 * 1e3,
        (y0 + geom.height * geom.cell_size_y) * 1e3,
    ]


def plot(report: DemoReport, seen: Observed, layout: Path, patch: str, path: Path) -> None:
    """Write :func:`figure` to ``path`` (PNG)."""
    import matplotlib.pyplot as plt

    fig = figure(report, seen, layout, patch)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def figure(report: DemoReport, seen: Observed, layout: Path, patch: str) -> Any:
    """Taxel ΔC, traction and deflection side by side at a frame of full load, plus the force
    over time and the centre-of-pressure path (a matplotlib Figure)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import SymLogNorm

    from tactile_contact.model.layout import load_layout
    from tactile_contact.model.sensor import value_count_farad

    xy = load_layout(layout).patch(patch).taxel_xy() * 1e3
    common = sorted(set(seen.traction) & set(seen.deflection) & set(seen.taxels))
    fig = plt.figure(figsize=(15, 8.5), layout="constrained")
    grid = fig.add_gridspec(2, 3, height_ratios=[1.25, 1])
    maps = []
    if common and report.stamps.size and report.loaded().any():
        # A representative frame, not the best one: among frames at full load, the one with the
        # median force error.
        full = np.nonzero(report.force_true >= 0.99 * report.force_true.max())[0]
        full = [j for j in full if min(abs(s - report.stamps[j]) for s in common) < 1e-6]
        err = np.abs(report.force_est[full] - report.force_true[full])
        i = int(full[np.argsort(err)[len(err) // 2]]) if full else int(np.argmax(report.force_true))
        t = min(common, key=lambda s: abs(s - report.stamps[i]))
        ax = fig.add_subplot(grid[0, 0])
        maps.append(ax)
        dc = seen.taxels[t] * 1e15
        # Symmetric and logarithmic beyond one 8-bit count: on a linear scale the taxel under
        # the indenter took the whole range and the ring of negative readings around it (the
        # layer bulging), a few counts each, which is the pattern to see, came out white.
        sensor = load_layout(layout).patch(patch).sensor
        count = float(value_count_farad(sensor.farad_per_count, sensor.shift)) * 1e15
        lim = max(float(np.abs(dc).max()), 2 * count)
        norm = SymLogNorm(linthresh=count, linscale=0.6, vmin=-lim, vmax=lim, base=10)
        sc = ax.scatter(xy[:, 0], xy[:, 1], c=dc, cmap="RdBu_r", norm=norm, s=90)
        fig.colorbar(sc, ax=ax, label=f"ΔC [fF] (linear within ±1 count = {count:.2f} fF)")
        ax.set_title("taxel ΔC (negative: the layer bulges)")
        for k, (name, scale, unit, cmap) in enumerate(
            [("traction", 1e-3, "kPa", "viridis"), ("deflection", 1e6, "µm", "RdBu_r")], start=1
        ):
            field_ = getattr(seen, name)[t] * scale
            ax = fig.add_subplot(grid[0, k])
            maps.append(ax)
            kw = {"vmin": 0} if name == "traction" else {"vmin": -np.abs(field_).max()}
            if name == "deflection":
                kw["vmax"] = np.abs(field_).max()
            im = ax.imshow(
                field_,
                origin="lower",
                extent=_extent(seen.geometry.get(name), field_.shape),
                cmap=cmap,
                **kw,
            )
            fig.colorbar(im, ax=ax, label=f"{name} [{unit}]")
            ax.plot(*(report.cop_true[i] * 1e3), "w+", ms=14, mew=2, label="true CoP")
            ax.plot(*(report.cop_est[i] * 1e3), "rx", ms=10, mew=2, label="estimated CoP")
            ax.scatter(xy[:, 0], xy[:, 1], s=4, c="k")
            ax.set_title(  # (two short lines: one long one ran into the colour bar)
                f"{name}, t = {t - report.stamps[0]:.2f} s\n"
                f"F {report.force_est[i]:.2f} N (true {report.force_true[i]:.2f} N)"
            )
            ax.legend(loc="lower right", fontsize=7)
        for a in maps:
            a.set_aspect("equal", adjustable="box")
            a.set_xlabel("x [mm]")
            a.set_ylabel("y [mm]")
    ts = report.stamps - (report.stamps[0] if report.stamps.size else 0)
    missed = report.missed()
    gap = "no contact reported (press between taxels: a gap in the skin)"
    ax = fig.add_subplot(grid[1, 0:2])
    ax.plot(ts, report.force_true, "k-", label="true force")
    ax.plot(ts[~missed], report.force_est[~missed], "r.", ms=3, label="reconstructed")
    if missed.any():
        ax.plot(ts[missed], report.force_true[missed], "o", mfc="none", mec="tab:blue", ms=6,
                label=gap)  # fmt: skip
    ax.set_xlabel("time [s]")
    ax.set_ylabel("total normal force [N]")
    ax.legend(fontsize=8)
    ax = fig.add_subplot(grid[1, 2])
    m = report.loaded()
    seen_ = m & report.seen()  # (an unreported frame's CoP is (0, 0): not an estimate)
    ax.plot(report.cop_true[m, 0] * 1e3, report.cop_true[m, 1] * 1e3, "k-", label="true CoP path")
    ax.plot(report.cop_est[seen_, 0] * 1e3, report.cop_est[seen_, 1] * 1e3, "r.", ms=3,
            label="estimated")  # fmt: skip
    if missed.any():
        ax.plot(report.cop_true[missed, 0] * 1e3, report.cop_true[missed, 1] * 1e3, "o",
                mfc="none", mec="tab:blue", ms=7, label="no contact reported")  # fmt: skip
    ax.scatter(xy[:, 0], xy[:, 1], s=4, c="grey")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    ax.legend(fontsize=7)
    fig.suptitle(
        "tactile_contact demo: simulated indenter → CAN → skin_driver → reconstruction "
        "(default bundle, not calibrated; 8-bit readings)"
    )
    return fig


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="tactile-contact demo", description=__doc__.split("\n")[0])
    p.add_argument("--layout", type=Path, default=DEFAULT_LAYOUT)
    p.add_argument("--bundles", type=Path, default=Path("bundles"))
    p.add_argument("--out", type=Path, default=Path("out"))
    p.add_argument("--duration", type=float, default=6.0, help="simulated sweep length [s]")
    p.add_argument("--period-ms", type=int, default=20, help="module period [ms]")
    args = p.parse_args(argv)
    if not (args.duration > 0 and args.period_ms > 0):
        p.error("--duration and --period-ms must be > 0")
    from tactile_contact.model.layout import LayoutError
    from tactile_contact.offline.build import build_layout
    from tactile_contact.offline.bundle import BundleError

    try:
        # (a no-op when the bundles are up to date; this main is a console script: 2 jobs)
        build_layout(args.layout, args.bundles, jobs=2)
    except (LayoutError, BundleError, OSError, ValueError) as exc:
        print(f"ERROR: {exc}", file=sys.stderr)
        return 1
    report, seen, patch = run(args.layout, args.bundles, args.duration, args.period_ms)
    for line in [*report.frame_lines(), "", *report.summary_lines()]:
        print(line)
    if not report.frames_published:
        print(
            f"ERROR: no contact summary arrived in {args.duration:g} s of simulation "
            "(the reconstruction's log above says why); no figure written",
            file=sys.stderr,
        )
        return 1
    png = args.out / "demo.png"
    plot(report, seen, args.layout, patch, png)
    print(f"wrote {png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
