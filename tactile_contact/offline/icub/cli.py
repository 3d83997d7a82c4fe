"""``tactile-contact-import-icub``: an iCub skin part's files → a layout YAML, with a report.

Usage::

    tactile-contact-import-icub PART.ini POSITIONS.txt -o LAYOUT.yaml [--boards A,B,...]
        [--skin-spec SPEC.xml] [--robot-skin SKIN.xml --wrapper WRAPPER.xml [--port NAME]]
        [--link FRAME] [--name NAME] [--bus BUS] [--split auto|part|board] [--force] [--quiet]

Prints what it read, every anomaly it absorbed (with slot and rows), where each module's
placement came from and, per patch, the fitted surface and the flattening's neighbour-distance
figures (docs/icub.md). A bad file is one ``ERROR: FILE:LINE: problem`` line and exit status 1.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from tactile_contact.model.layout import LayoutError
from tactile_contact.offline.icub.errors import IcubFileError
from tactile_contact.offline.icub.importer import SPLITS, import_part


def _boards(text: str) -> tuple[int, ...]:
    try:
        out = tuple(int(t, 0) for t in text.replace(" ", "").split(",") if t)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated CAN addresses, e.g. 13,12; got {text!r}"
        ) from None
    bad = [a for a in out if not 0 <= a <= 15]
    if not out or bad:
        raise argparse.ArgumentTypeError(f"CAN addresses are 0..15, got {text!r}")
    if len(set(out)) != len(out):
        raise argparse.ArgumentTypeError(f"an address is listed twice in {text!r}")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="tactile-contact-import-icub",
        description="Import an iCub skin part (skinGui .ini + positions .txt) as a layout YAML.",
    )
    ap.add_argument("ini", help="skinGui .ini of the part (icub-main app/skinGui/conf/skinGui)")
    ap.add_argument("positions", help="positions .txt of the part (app/skinGui/conf/positions)")
    ap.add_argument("-o", "--output", required=True, help="layout YAML to write")
    ap.add_argument(
        "--boards",
        type=_boards,
        help="CAN addresses of the part's boards in slot order (slot // 16 -> address), "
        "e.g. 13,12; default: the .ini's cardid line (warned: it may be stale)",
    )
    ap.add_argument(
        "--skin-spec", help="the robot's *-skinSpec.xml: enabled triangles, shift, cdcOffset"
    )
    ap.add_argument("--robot-skin", help="the robot's *-skin.xml (board addresses in port order)")
    ap.add_argument("--wrapper", help="the robot's *-skin_wrapper.xml (the part's port slice)")
    ap.add_argument("--port", help="wrapper port of the part (default: the .ini's robotPart)")
    ap.add_argument("--link", help="link frame of the positions (default: the file's name line)")
    ap.add_argument("--name", help="patch name (default: the .ini's robotPart)")
    ap.add_argument("--bus", default="", help="the CAN bus of the part's patches (layout 'bus')")
    ap.add_argument(
        "--split",
        choices=SPLITS,
        default="auto",
        help="one patch for the part, one per board, or auto (the part unless one surface "
        "does not describe it)",
    )
    ap.add_argument("--force", action="store_true", help="overwrite an existing output file")
    ap.add_argument("--quiet", action="store_true", help="print only warnings and errors")
    args = ap.parse_args(argv)
    out = Path(args.output)
    if out.exists() and not args.force:
        print(f"ERROR: {out} exists; pass --force to overwrite it", file=sys.stderr)
        return 1
    command = "tactile-contact-import-icub " + shlex.join(
        sys.argv[1:] if argv is None else list(argv)
    )
    try:
        result = import_part(
            args.ini,
            args.positions,
            boards=args.boards,
            skin_spec=args.skin_spec,
            robot_skin=args.robot_skin,
            wrapper=args.wrapper,
            port=args.port,
            link=args.link,
            name=args.name,
            bus=args.bus,
            split=args.split,
            command=command,
        )
    except (IcubFileError, LayoutError, ValueError) as exc:
        print(f"ERROR: {exc}", file=sys.stderr)
        return 1
    rep = result.report
    for line in rep.lines():
        if not args.quiet or "WARNING" in line or "OUTSIDE" in line:
            print(line)
    try:
        out.write_text(result.text, encoding="utf-8")
    except OSError as exc:
        print(f"ERROR: {out}: cannot write: {exc.strerror or exc}", file=sys.stderr)
        return 1
    bad = [p.name for p in rep.patches if not p.within_targets]
    if bad:
        print(
            f"WARNING: patch(es) {', '.join(bad)} outside the flattening targets: "
            "contacts there are reconstructed on a distorted map (docs/icub.md)",
            file=sys.stderr,
        )
    n = sum(p.modules for p in rep.patches)
    print(
        f"wrote {out}: {len(rep.patches)} patch(es), {n} modules; build the bundles with "
        f"tactile-contact-build {out} -o bundles/"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
