"""``tactile-contact``: run the pipeline without ``ros2 launch``, record and replay bags.

    tactile-contact bringup [--simulate] [--duration S] [--record BAG]   the graph in one process
    tactile-contact replay BAG [--rate R]          replay recorded taxels into a reconstruction node
    tactile-contact demo                           the end-to-end demo (``make demo``)

Errors are printed as ``ERROR: …`` with exit status 1.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from pathlib import Path


def _add_graph_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--layout", default="", help="patch layout YAML (default: hexagon patch)")
    p.add_argument("--bundles", default="bundles", help="folder of matrix bundles")
    p.add_argument("--namespace", default="")


def _bringup(args: argparse.Namespace) -> int:
    import rclpy
    from rclpy.context import Context

    from tactile_contact.ros.bag import BagRecorder
    from tactile_contact.ros.bringup import GraphConfig, running_graph
    from tactile_contact.ros.topics import pipeline_topics

    config = GraphConfig(
        layout=args.layout,
        bundles_dir=args.bundles,
        simulate=args.simulate,
        interface=args.interface or ("virtual" if args.simulate else "socketcan"),
        channel=args.channel or ("tactile_contact" if args.simulate else "can0"),
        scenario=args.scenario,
        namespace=args.namespace,
        reconstruction={"follow_contacts": False} if args.no_follow else {},
    )
    context = Context()
    rclpy.init(context=context)
    recorder = None
    try:
        with running_graph(config, context) as executor:
            if args.record:
                node = rclpy.create_node("tactile_contact_recorder", context=context)
                executor.add_node(node)
                topics = pipeline_topics(config.layout_path, tuple(args.record_topics))
                recorder = BagRecorder(node, args.record, topics, storage=args.storage)
            deadline = time.monotonic() + args.duration if args.duration > 0 else None
            while context.ok() and (deadline is None or time.monotonic() < deadline):
                executor.spin_once(timeout_sec=0.1)
    except KeyboardInterrupt:
        pass
    finally:
        if recorder is not None:
            recorder.close()
            print(f"recorded {sum(recorder.counts.values())} messages to {args.record}")
        rclpy.try_shutdown(context=context)
    return 0


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
    context = Context()
    rclpy.init(context=context)
    nodes = []
    try:
        # A replay must reconstruct every recorded frame, even when this machine is slower than
        # the one that recorded: a queue as deep as the bag (up to the 1000 the parameter allows)
        # instead of the live default of 1.
        recon = ContactReconstructionNode(
            context=context,
            parameter_overrides=[
                rclpy.parameter.Parameter("bundles_dir", value=args.bundles),
                rclpy.parameter.Parameter("queue_depth", value=min(max(len(raw), 1), 1000)),
            ],
        )
        nodes.append(recon)
        player_node = rclpy.create_node("tactile_contact_player", context=context)
        nodes.append(player_node)
        # Only the taxel streams by default: the recorded summaries would mix with the node's own.
        player = BagPlayer(player_node, args.bag, topics=args.topics or taxels, rate=args.rate)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(recon)
        executor.add_node(player_node)
        thread = threading.Thread(target=player.play, daemon=True)
        time.sleep(args.delay)  # let discovery match this process with other subscribers
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
        print(f"replayed {player.published} messages from {args.bag}")
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown(context=context)
    return 0


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
    b.add_argument("--duration", type=float, default=0.0, help="seconds to run (0: until ^C)")
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
        help="solve every frame on its own (follow_contacts false): a recording any replay "
        "reproduces frame for frame",
    )
    r = sub.add_parser("replay", help="replay a bag's taxel arrays into a reconstruction node")
    r.add_argument("bag")
    r.add_argument("--bundles", default="bundles")
    r.add_argument("--rate", type=float, default=1.0)
    r.add_argument(
        "--delay",
        type=float,
        default=0.5,
        help="seconds to wait before playing, for subscribers in other processes to match",
    )
    r.add_argument(
        "--topics", nargs="*", default=[], help="topics to replay (default: the TaxelArray ones)"
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
