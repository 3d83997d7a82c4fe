"""The guard that ends what a test leaves running (test/leftovers.py, conftest's
no_leftover_process): a real child process left alive is named and killed; one that ends
within the grace is not; one that was there before is left alone."""

from __future__ import annotations

import subprocess
import sys

from test.leftovers import descendants, end_leftovers


def test_a_process_left_running_is_named_and_killed() -> None:
    before = descendants()
    kept = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        mark = descendants()
        assert kept.pid in mark and kept.pid not in before
        left = subprocess.Popen(["sleep", "61"])
        ends = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(0.3)"])
        named = end_leftovers(mark, grace_s=2.0)
        assert len(named) == 1 and named[0].startswith(f"pid {left.pid}: sleep 61"), named
        assert left.wait(timeout=5) == -9  # SIGKILL
        assert ends.wait(timeout=5) == 0
        assert kept.poll() is None  # (there before: not this call's to end)
    finally:
        kept.kill()
        kept.wait()
    assert end_leftovers(before, grace_s=0.5) == []
