"""``tactile-contact bringup`` and ``replay`` say what happened (issue 27): a summary at the end
(frames, contacts, peak force, drops), exit status 1 with ``ERROR:`` lines when they could not
do their job (no bus, a patch without a bundle, nothing replayed into a reconstruction), bad
numbers refused, and a replay whose topics can be found by ``ros2 topic echo`` started during
its ``--delay``.

The commands run in processes of their own, as a user types them (the shipped session bag,
bundles built here, python-can's socketcan where this kernel has none, python-can's virtual bus
for the simulated skin).
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.ros

ROOT = Path(__file__).resolve().parents[1]
BAG = ROOT / "test" / "data" / "hexagon_session"
VENV_BIN = Path(sys.executable).parent


@pytest.fixture(scope="module")
def bundles(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from tactile_contact.offline.build import build_layout

    out = tmp_path_factory.mktemp("bundles")
    build_layout(ROOT / "config" / "hexagon_patch.yaml", out)
    return out


def _cli(*args: str, timeout_s: float = 180.0) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "tactile_contact.ros.cli", *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=timeout_s,
    )


@pytest.mark.parametrize(
    "args",
    [
        ("bringup", "--duration", "-5"),
        ("bringup", "--duration", "nan"),
        ("replay", str(BAG), "--rate", "-1"),
        ("replay", str(BAG), "--delay", "-2"),
    ],
    ids=["duration", "duration-nan", "rate", "delay"],
)
def test_negative_durations_and_rates_are_refused(args: tuple[str, ...]) -> None:
    done = _cli(*args, timeout_s=60.0)
    assert done.returncode == 2, done.stdout + done.stderr
    assert "must be" in done.stderr and "Traceback" not in done.stderr, done.stderr


def test_bringup_without_its_bus_fails_with_the_reason(tmp_path: Path, bundles: Path) -> None:
    done = _cli(
        "bringup",
        "--interface",
        "socketcan",
        "--channel",
        "tcnone0",
        "--bundles",
        str(bundles),
        "--duration",
        "2",
    )
    assert done.returncode == 1, done.stdout + done.stderr
    assert "ERROR: the CAN bus never opened: cannot open CAN bus socketcan:tcnone0" in done.stderr
    assert "skin_driver: bus socketcan:tcnone0: 0 CAN frames" in done.stdout, done.stdout
    assert "Traceback" not in done.stderr


def test_bringup_without_bundles_fails_naming_the_build_command(tmp_path: Path) -> None:
    """No --duration: with nothing to reconstruct it stops by itself, not at Ctrl-C."""
    missing = tmp_path / "no_bundles"
    done = _cli(
        "bringup", "--interface", "virtual", "--channel", f"nob{os.getpid()}",
        "--bundles", str(missing),
    )  # fmt: skip
    assert done.returncode == 1, done.stdout + done.stderr
    errors = [x for x in done.stderr.splitlines() if x.startswith("ERROR: patch hexagon")]
    assert errors and "tactile-contact-build" in errors[0] and str(missing) in errors[0], (
        done.stderr
    )


def test_bringup_says_what_it_saw(bundles: Path) -> None:
    """A simulated press: a line when it starts and ends, a summary with its force at the end,
    the parameters in one line per node."""
    done = _cli(
        "bringup", "--simulate", "--scenario", "press", "--bundles", str(bundles),
        "--channel", f"says{os.getpid()}", "--duration", "9",
    )  # fmt: skip
    out, err = done.stdout, done.stderr
    assert done.returncode == 0, out + err
    assert len(re.findall(r"\]: parameters?\b", err)) == 3, err  # one line per node
    assert re.search(r"patch hexagon: contact: [0-9.]+ N at", err), err
    m = re.search(
        r"contact_reconstruction: hexagon: (\d+) frames, (\d+) contact\(s\) in (\d+) frames, "
        r"peak force ([0-9.]+) N",
        out,
    )
    assert m, out
    frames, contacts, _, peak = int(m[1]), int(m[2]), int(m[3]), float(m[4])
    # (the peak is of single frames: a frame with a late module can read high on a busy machine)
    assert frames > 50 and contacts >= 1 and peak > 1.0, out
    assert re.search(r"skin_driver: bus virtual:says\d+: \d+ CAN frames, 0 rejected", out), out
    assert re.search(r"skin_driver: hexagon: \d+ taxel messages published", out), out


def test_replay_without_bundles_fails_naming_the_build_command(tmp_path: Path) -> None:
    done = _cli("replay", str(BAG), "--bundles", str(tmp_path / "none"), "--delay", "0")
    assert done.returncode == 1, done.stdout + done.stderr
    assert "tactile-contact-build" in done.stderr and "replayed" not in done.stdout, done.stdout


def test_replay_ends_with_a_summary(bundles: Path) -> None:
    done = _cli("replay", str(BAG), "--bundles", str(bundles), "--rate", "0", "--delay", "0")
    assert done.returncode == 0, done.stdout + done.stderr
    m = re.search(r"replayed (\d+) messages", done.stdout)
    assert m and int(m[1]) > 100, done.stdout
    m2 = re.search(r"contact_reconstruction: hexagon: (\d+) frames, (\d+) contact", done.stdout)
    assert m2 and int(m2[1]) == int(m[1]) and int(m2[2]) >= 1, done.stdout


def test_ros2_topic_echo_started_during_the_delay_finds_the_type(bundles: Path) -> None:
    """``ros2 topic echo`` learns the type from a publisher that exists when it starts: the
    replay says on stdout when its topics exist, and its --delay runs from there."""
    ros2 = VENV_BIN / "ros2"
    if not ros2.exists():
        reason = f"ros2 not in {VENV_BIN} (ros2cli: make ros-launch)"
        if os.environ.get("TACTILE_REQUIRE_LAUNCH") == "1":
            pytest.fail(f"TACTILE_REQUIRE_LAUNCH=1 but {reason}")
        pytest.skip(reason)
    replay = subprocess.Popen(
        [sys.executable, "-m", "tactile_contact.ros.cli", "replay", str(BAG),
         "--bundles", str(bundles), "--delay", "8"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    try:
        assert replay.stdout is not None
        lines = []
        end = time.monotonic() + 120.0
        while time.monotonic() < end:
            line = replay.stdout.readline()
            lines.append(line)
            if not line or line.startswith("publishing "):
                break
        assert lines[-1].startswith("publishing /hexagon/contact"), "".join(lines)
        # (--no-daemon: none left running after the test; --spin-time: discovery on a busy
        # 2-core machine can take longer than ros2cli's 0.5 s default)
        echo = subprocess.run(
            [
                str(ros2),
                "topic",
                "echo",
                "--once",
                "--no-daemon",
                "--spin-time",
                "3",
                "/hexagon/contact",
            ],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert echo.returncode == 0, echo.stdout + echo.stderr
        assert "total_force" in echo.stdout and "Could not determine" not in echo.stderr
    finally:
        if replay.poll() is None:
            replay.send_signal(signal.SIGINT)
        replay.wait(timeout=60)
