"""``tactile-contact``: run the pipeline without ``ros2 launch``, record and replay bags.

    tactile-contact bringup [--simulate] [--duration S] [--record BAG]   the graph in one process
    tactile-contact replay BAG [--rate R]          replay recorded taxels into a reconstruction node
    tactile-contact demo                           the end-to-end demo (``make demo``)

Each run ends with a summary (frames, contacts and their peak force, anything dropped). Exit
status 1, with ``ERROR: …`` lines, when the run could not do its job: bad arguments, no bus, a
patch without a usable bundle, nothing replayed into a reconstruction.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any


def _seconds(text: str) -> float:
    """An argparse type: a finite number of seconds ≥ 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not (value >= 0 and value != float("inf")):
        raise argparse.ArgumentTypeError(f"{text}: must be a finite number ≥ 0")
    return value


def _rate(text: str) -> float:
    """An argparse type: a playback speed factor ≥ 0 (0: as fast as possible)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (value >= 0 and value != float("inf")):
        raise argparse.ArgumentTypeError(f"{text}: must be ≥ 0 (1: recorded pace, 0: at once)")
    return value


def _report(lines: list[str], problems: list[str]) -> int:
    """Print the summary lines (stdout) and the problems as ERROR lines (stderr); exit status."""
    for line in lines:
        print(line)
    for problem in problems:
        print(f"ERROR: {problem}", file=sys.stderr)
    return 1 if problems else 0


def _nothing_to_reconstruct(nodes: Iterable[Any]) -> bool:
    """Whether the graph's reconstruction serves no patch at all (no usable bundle): running
    on would only move frames nobody turns into contacts."""
    from tactile_contact.ros.contact_reconstruction import ContactReconstructionNode

    recon = [n for n in nodes if isinstance(n, ContactReconstructionNode)]
    return bool(recon) and not any(n.pipelines for n in recon)


def _add_graph_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--layout", default="", help="patch layout YAML (default: hexagon patch)")
    p.add_argument("--bundles", default="bundles", help="folder of matrix bundles")
    p.add_argument("--namespace", default="")


def _bringup(args: argparse.Namespace) -> int:
    import rclpy
    from rclpy.context import Context

    from tactile_contact.ros.bag import BagRecorder
    from tactile_contact.ros.bringup import GraphConfig, running_graph, summarise
    from tactile_contact.ros.topics import pipeline_topics

    config = GraphConfig(
        layout=args.layout,
        bundles_dir=args.bundles,
        simulate=args.simulate,
        interface=args.interface or ("virtual" if args.simulate else "socketcan"),
        channel=args.channel or ("tactile_contact" if args.simulate else "can0"),
        scenario=args.scenario,
        namespace=args.namespace,
        reconstruction={"follow_contacts": False, "fuse_frames": False} if args.no_follow else {},
    )
    context = Context()
    rclpy.init(context=context)
    recorder = None
    lines: list[str] = []
    problems: list[str] = []
    try:
        with running_graph(config, context) as executor:
            try:
                if args.record:
                    node = rclpy.create_node("tactile_contact_recorder", context=context)
                    executor.add_node(node)
                    topics = pipeline_topics(config.layout_path, tuple(args.record_topics))
                    recorder = BagRecorder(node, args.record, topics, storage=args.storage)
                deadline = time.monotonic() + args.duration if args.duration > 0 else None
                while context.ok() and (deadline is None or time.monotonic() < deadline):
                    executor.spin_once(timeout_sec=0.1)
                    if _nothing_to_reconstruct(executor.get_nodes()):
                        break  # (said in the summary: no patch has a usable bundle)
            except KeyboardInterrupt:
                pass
            finally:  # (before the graph is destroyed: its nodes hold the counts)
                lines, problems = summarise(executor.get_nodes())
    except KeyboardInterrupt:
        pass
    finally:
        if recorder is not None:
            recorder.close()
            lines.append(f"recorded {sum(recorder.counts.values())} messages to {args.record}")
        rclpy.try_shutdown(context=context)
    return _report(lines, problems)


def _replay(args: argparse.Namespace) -> int:
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor

    from tactile_contact.ros.bag import BagError, BagPlayer, load_raw
    from tactile_contact.ros.contact_reconstruction import ContactReconstructionNode

    # The bag is checked before any node starts: a missing topic, a truncated file or an
    # older message definition is one clear error, not a half-started graph.
    raw = load_raw(args.bag, args.topics or None)
    taxels = sorted({t for t, _, _, msgtype in raw if msgtype.endswith("/TaxelArray")})
    if not taxels:
        held = sorted({f"{t} ({msgtype})" for t, _, _, msgtype in raw})
        raise BagError(
            f"{args.bag}: no tactile_contact/msg/TaxelArray topic to replay into the "
            f"reconstruction; it holds {', '.join(held) or 'no message'}"
        )
    # Patches by their taxel topics (<namespace>/<patch>/taxels).
    patches = {t.rstrip("/").split("/")[-2]: t for t in taxels if t.count("/") >= 2}
    context = Context()
    rclpy.init(context=context)
    nodes = []
    lines: list[str] = []
    problems: list[str] = []
    try:
        # A replay must reconstruct every recorded frame, even when this machine is slower than
        # the one that recorded: a queue as deep as the bag (up to the 1000 the parameter allows)
        # instead of the live default of 1.
        recon = ContactReconstructionNode(
            context=context,
            parameter_overrides=[
                rclpy.parameter.Parameter("bundles_dir", value=args.bundles),
                rclpy.parameter.Parameter("queue_depth", value=min(max(len(raw), 1), 1000)),
            ]
            + [
                rclpy.parameter.Parameter(name, value=False)
                for name in ("follow_contacts", "fuse_frames")
                if args.no_follow
            ],
        )
        nodes.append(recon)
        unserved = {p: e for p, e in recon.load_errors.items() if p in patches or p == "*"}
        unserved.update(
            {
                p: f"no bundle in {args.bundles}; build it with {recon.build_command()}"
                for p in patches
                if p not in recon.pipelines and p not in unserved
            }
        )
        if unserved:
            # Nothing to replay into: the bag's frames would go out and come to nothing.
            return _report(
                recon.summary(), [f"patch {p}: {e}" for p, e in sorted(unserved.items())]
            )
        player_node = rclpy.create_node("tactile_contact_player", context=context)
        nodes.append(player_node)
        # Only the taxel streams by default: the recorded summaries would mix with the node's own.
        player = BagPlayer(player_node, args.bag, topics=args.topics or taxels, rate=args.rate)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(recon)
        executor.add_node(player_node)
        thread = threading.Thread(target=player.play, daemon=True)
        # Every topic exists from here on: a `ros2 topic echo` (which needs a publisher to
        # learn the type) or rviz2 started now matches before the first message.
        outputs = ", ".join(
            p.pub_contact.topic_name for p in recon.pipelines.values() if p.name in patches
        )
        print(
            f"publishing {outputs} (ContactState); playing {args.bag} in {args.delay:g} s",
            flush=True,
        )
        start = time.monotonic() + args.delay
        while time.monotonic() < start:
            executor.spin_once(timeout_sec=min(0.05, max(start - time.monotonic(), 0.0)))
        thread.start()
        while thread.is_alive():
            executor.spin_once(timeout_sec=0.05)

        # Drain the queue: on until the node has taken every frame played, or 1 s brings none.
        def taken() -> int:
            return sum(p.stats.frames for p in recon.pipelines.values())

        seen, quiet_until = taken(), time.monotonic() + 1.0
        while seen < player.published and time.monotonic() < quiet_until:
            executor.spin_once(timeout_sec=0.05)
            if taken() > seen:
                seen, quiet_until = taken(), time.monotonic() + 1.0
        for _ in range(4):
            executor.spin_once(timeout_sec=0.05)
        for pipe in recon.pipelines.values():
            pipe.end_contact()
        lines = [f"replayed {player.published} messages from {args.bag}"]
        lines += [f"contact_reconstruction: {line}" for line in recon.summary()]
        if taken() == 0:
            problems.append(
                f"no frame of {args.bag} reached the reconstruction "
                f"({player.published} messages published on {', '.join(taxels)})"
            )
        elif taken() < player.published:
            lines.append(f"{player.published - taken()} frames not taken by the reconstruction")
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown(context=context)
    return _report(lines, problems)


def main(argv: list[str] | None = None) -> int:
    from tactile_contact.ros.topics import STREAMS

    parser = argparse.ArgumentParser(prog="tactile-contact", description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    b = sub.add_parser("bringup", help="simulator/driver/reconstruction in one process")
    _add_graph_args(b)
    b.add_argument("--simulate", action="store_true", help="simulated skin on a virtual bus")
    b.add_argument("--interface", default="", help="python-can interface (socketcan on robots)")
    b.add_argument("--channel", default="", help="CAN channel (can0 on robots)")
    b.add_argument("--scenario", default="sweep", choices=["sweep", "press", "idle"])
    b.add_argument("--duration", type=_seconds, default=0.0, help="seconds to run (0: until ^C)")
    b.add_argument("--record", default="", help="record the pipeline's topics to this bag")
    b.add_argument(
        "--record-topics",
        nargs="+",
        default=list(STREAMS),
        choices=list(STREAMS),
        help="per-patch streams to record",
    )
    b.add_argument("--storage", default="mcap", choices=["mcap", "sqlite3"])
    b.add_argument(
        "--no-follow",
        action="store_true",
        help="solve every frame on its own (follow_contacts and fuse_frames false): a "
        "recording any replay reproduces frame for frame",
    )
    r = sub.add_parser("replay", help="replay a bag's taxel arrays into a reconstruction node")
    r.add_argument("bag")
    r.add_argument("--bundles", default="bundles")
    r.add_argument(
        "--rate", type=_rate, default=1.0, help="playback speed (1: recorded pace, 0: at once)"
    )
    r.add_argument(
        "--delay",
        type=_seconds,
        default=0.5,
        help="seconds to wait, once every topic exists (said on stdout), before playing: "
        "time to start `ros2 topic echo` or rviz2 in another terminal",
    )
    r.add_argument(
        "--topics", nargs="*", default=[], help="topics to replay (default: the TaxelArray ones)"
    )
    r.add_argument(
        "--no-follow",
        action="store_true",
        help="solve every frame on its own (follow_contacts and fuse_frames false), as a "
        "recording made with bringup --no-follow was",
    )
    d = sub.add_parser("demo", help="end-to-end demo with figures and a PNG")
    d.add_argument("rest", nargs=argparse.REMAINDER)
    args = parser.parse_args(argv)
    try:
        if args.command == "bringup":
            return _bringup(args)
        if args.command == "replay":
            if not Path(args.bag).exists():
                raise FileNotFoundError(f"{args.bag}: no such bag")
            return _replay(args)
        from tactile_contact.ros import demo

        return demo.main(args.rest)
    except KeyboardInterrupt:
        return 130
    except (OSError, ValueError, RuntimeError) as exc:  # BagError is a RuntimeError
        print(f"ERROR: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
