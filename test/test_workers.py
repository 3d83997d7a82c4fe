"""The split of a skin over reconstruction workers (tactile_contact.ros.workers, no ROS).

Checked against an independent reference: for small skins, every possible split is tried and
the greedy split's busiest worker is compared with the best one's (the 4/3 bound of the
longest-processing-time rule).
"""

from __future__ import annotations

import itertools
import random

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tactile_contact.ros.workers import (
    BUS_SLACK,
    MISSING_AFTER_S,
    SILENT_AFTER_S,
    Roster,
    WorkerInfo,
    assign_patches,
    default_workers,
    worker_patches,
)

names = st.text(alphabet="abcdefghij_0123456789", min_size=1, max_size=8)
skins = st.dictionaries(names, st.integers(1, 5000), min_size=0, max_size=40)


def _loads(taxels: dict[str, int], split: list[tuple[str, ...]]) -> list[int]:
    return [sum(taxels[p] for p in names) for names in split]


@given(skins, st.integers(1, 8))
def test_every_patch_goes_to_exactly_one_worker(taxels: dict[str, int], n: int) -> None:
    split = assign_patches(taxels, n)
    assert len(split) == n
    flat = [p for names in split for p in names]
    assert sorted(flat) == sorted(taxels)  # each once, none lost
    assert all(list(names) == sorted(names) for names in split)


@given(skins, st.integers(1, 8), st.randoms(use_true_random=False))
def test_the_split_does_not_depend_on_the_order_patches_are_listed(
    taxels: dict[str, int], n: int, rnd: random.Random
) -> None:
    items = list(taxels.items())
    rnd.shuffle(items)
    assert assign_patches(dict(items), n) == assign_patches(taxels, n)
    # every worker computes its own share alone and they agree
    assert [worker_patches(dict(items), k, n) for k in range(n)] == assign_patches(taxels, n)


@given(skins.filter(bool), st.integers(1, 8))
def test_balanced_within_one_patch_of_the_mean(taxels: dict[str, int], n: int) -> None:
    loads = _loads(taxels, assign_patches(taxels, n))
    biggest = max(taxels.values())
    assert max(loads) <= sum(loads) / n + biggest
    if len(taxels) >= n:
        assert min(loads) > 0  # nobody idles while there is work for everyone


@given(st.dictionaries(names, st.integers(1, 400), min_size=1, max_size=7), st.integers(2, 3))
def test_within_four_thirds_of_the_best_split(taxels: dict[str, int], n: int) -> None:
    best = min(
        max(sum(taxels[p] for p, w in zip(taxels, owners, strict=True) if w == k) for k in range(n))
        for owners in itertools.product(range(n), repeat=len(taxels))
    )
    assert max(_loads(taxels, assign_patches(taxels, n))) <= 4 / 3 * best + 1e-9


def test_a_robot_skin_splits_evenly() -> None:
    # iCub-like part sizes (taxels): 2 forearms of 24 modules, 2 upper arms of 40, ...
    parts = {"forearm": 240, "upper_arm": 400, "upper_leg": 680, "lower_leg": 380, "torso": 440}
    taxels = {f"{side}_{p}": n for side in "lr" for p, n in parts.items()}
    loads = _loads(taxels, assign_patches(taxels, 2))
    assert loads == [2140, 2140]
    loads = _loads(taxels, assign_patches(taxels, 3))
    assert max(loads) - min(loads) <= 240


bus_names = st.sampled_from(["arm", "leg", "torso", "hand", "head"])


@st.composite
def skins_on_buses(draw: st.DrawFn) -> tuple[dict[str, int], dict[str, str]]:
    taxels = draw(skins)
    # some patches left out of the mapping: each is a bus of its own
    buses = {p: draw(bus_names) for p in taxels if draw(st.integers(0, 5))}
    return taxels, buses


@given(skins_on_buses(), st.integers(1, 8), st.randoms(use_true_random=False))
def test_with_buses_every_patch_once_stable_and_within_the_slack(
    skin: tuple[dict[str, int], dict[str, str]], n: int, rnd: random.Random
) -> None:
    taxels, buses = skin
    split = assign_patches(taxels, n, buses)
    assert len(split) == n
    assert sorted(p for names in split for p in names) == sorted(taxels)
    assert all(list(names) == sorted(names) for names in split)
    items = list(taxels.items())
    rnd.shuffle(items)
    bus_items = list(buses.items())
    rnd.shuffle(bus_items)
    assert assign_patches(dict(items), n, dict(bus_items)) == split
    assert [worker_patches(dict(items), k, n, buses) for k in range(n)] == split
    if taxels:
        plain = max(_loads(taxels, assign_patches(taxels, n)))
        assert max(_loads(taxels, split)) <= (1 + BUS_SLACK) * plain + 1e-9


def _buses_split(split: list[tuple[str, ...]], buses: dict[str, str]) -> int:
    """How many buses have patches with more than one worker."""
    owners: dict[str, set[int]] = {}
    for k, names in enumerate(split):
        for p in names:
            owners.setdefault(buses[p], set()).add(k)
    return sum(1 for w in owners.values() if len(w) > 1)


def test_the_robot_keeps_its_buses_whole_where_balance_allows() -> None:
    from pathlib import Path

    from tactile_contact.model.layout import load_layout

    layout = load_layout(Path(__file__).parents[1] / "config" / "icub_robot.yaml")
    taxels = {p.name: len(p.taxel_ids()) for p in layout.patches}
    buses = {p.name: p.bus for p in layout.patches}
    assert len(set(buses.values())) == 7
    for n, most_split in ((2, 0), (3, 0), (4, 1), (6, 1)):
        split = assign_patches(taxels, n, buses)
        assert _buses_split(split, buses) <= most_split, n
        # patch by patch, every bus is shared (what the buses save)
        assert _buses_split(assign_patches(taxels, n), buses) >= 4
    # 2 workers: the 7 buses whole, 2124 and 1804 taxels (1964 each patch by patch: 8 % more)
    assert sorted(_loads(taxels, assign_patches(taxels, 2, buses))) == [1804, 2124]


def test_buses_too_uneven_to_keep_whole_fall_back_to_patches() -> None:
    # one bus holds nearly everything: kept whole it would leave the other worker idle
    taxels = {f"p{i}": 100 for i in range(10)}
    buses = {p: ("big" if i < 9 else "small") for i, p in enumerate(taxels)}
    split = assign_patches(taxels, 2, buses)
    assert sorted(_loads(taxels, split)) == [500, 500]
    # one bus, or no buses named: the patch-by-patch split
    assert assign_patches(taxels, 3, dict.fromkeys(taxels, "one")) == assign_patches(taxels, 3)
    assert assign_patches(taxels, 3, {}) == assign_patches(taxels, 3)


def test_bad_arguments_are_named() -> None:
    with pytest.raises(ValueError, match="workers must be an integer >= 1, got 0"):
        assign_patches({"a": 1}, 0)
    with pytest.raises(ValueError, match="patch 'a': taxel count must be an integer >= 1"):
        assign_patches({"a": 0}, 2)
    with pytest.raises(ValueError, match=r"worker index must be within 0\.\.1, got 2"):
        worker_patches({"a": 1}, 2, 2)


def test_default_workers_is_the_cores_at_most_one_per_patch() -> None:
    import os

    cores = len(os.sched_getaffinity(0))
    assert default_workers() == cores
    assert default_workers(1) == 1
    assert default_workers(1000) == cores


def _info(name: str, patches: tuple[str, ...], started: float) -> WorkerInfo:
    return WorkerInfo(name, 0, 2, patches, started)


def test_a_silent_worker_is_reported_and_a_heard_one_is_not() -> None:
    roster = Roster()
    roster.heard(_info("host/1", ("a", "b"), 10.0), now=100.0)
    roster.heard(_info("host/2", ("c",), 11.0), now=100.0)
    roster.heard(_info("host/2", ("c",), 11.0), now=100.4)
    assert roster.silent(100.0 + SILENT_AFTER_S) == []
    assert [w.worker for w in roster.silent(100.0 + SILENT_AFTER_S + 0.01)] == ["host/1"]
    assert [w.worker for w in roster.forget(5.0, now=106.0)] == ["host/1", "host/2"]
    assert roster.workers == {}


def test_a_patch_claimed_twice_is_served_by_the_older_claim() -> None:
    roster = Roster()
    old = _info("a/1", ("p1", "p2"), 10.0)
    new = _info("b/7", ("p2", "p3"), 12.0)
    roster.heard(old, now=50.0)
    roster.heard(new, now=50.0)
    twice = roster.served_twice(50.1)
    assert list(twice) == ["p2"] and [w.worker for w in twice["p2"]] == ["a/1", "b/7"]
    assert {p: w.worker for p, w in roster.taken(("p2", "p3"), new, 50.1).items()} == {"p2": "a/1"}
    assert roster.taken(("p1", "p2"), old, 50.1) == {}  # the older one keeps serving
    # the older one dies: its patch is nobody's, the younger may serve it
    assert roster.taken(("p2", "p3"), new, 50.0 + SILENT_AFTER_S + 0.1) == {}


def test_a_worker_of_a_split_never_heard_is_missing_after_the_grace() -> None:
    roster = Roster()
    roster.heard(WorkerInfo("host/1", 0, 3, ("a",), 10.0), now=100.0)
    roster.heard(WorkerInfo("host/2", 2, 3, ("c",), 10.0), now=101.0)
    assert roster.missing(100.0 + MISSING_AFTER_S - 0.1) == []  # still starting
    assert roster.missing(100.0 + MISSING_AFTER_S) == [(1, 3)]
    roster.heard(WorkerInfo("host/3", 1, 3, ("b",), 30.0), now=125.0)
    assert roster.missing(126.0) == []
    # patches named by hand (count 0) are no split; a split nobody of is left is forgotten
    roster.heard(WorkerInfo("host/4", -1, 0, ("d",), 10.0), now=130.0)
    roster.heard(WorkerInfo("host/5", 0, 2, ("a", "b"), 10.0), now=130.0)
    assert roster.missing(130.0 + MISSING_AFTER_S) == [(1, 2)]
    del roster.workers["host/5"]
    assert roster.missing(130.0 + MISSING_AFTER_S) == []


@pytest.mark.ros
def test_the_monitor_says_which_worker_of_a_split_was_never_heard(ros_context: object) -> None:
    from tactile_contact.ros.worker_monitor import WorkerMonitor

    node = WorkerMonitor(context=ros_context)
    try:
        node.roster.heard(WorkerInfo("host/1", 0, 2, ("forearm",), 10.0), now=100.0)
        (ok,) = node.statuses(100.2)
        assert ok.level == b"\x00" and ok.message == "1 worker(s) serving 1 patch(es)"
        node.roster.heard(
            WorkerInfo("host/1", 0, 2, ("forearm",), 10.0), now=100.0 + MISSING_AFTER_S
        )
        (bad,) = node.statuses(100.0 + MISSING_AFTER_S)
        assert bad.level == b"\x02"
        assert "worker 1 of 2 never heard (its patches not served)" in bad.message
        assert {v.key: v.value for v in bad.values}["missing"] == "1/2"
    finally:
        node.destroy_node()


def test_a_relaunched_split_counts_only_its_own_workers_as_heard() -> None:
    """Workers relaunched with the same count while the monitor runs on: the indexes the first
    launch's workers had do not count for the second's (a review found worker 1 of the
    relaunch never reported)."""
    roster = Roster()
    roster.heard(WorkerInfo("a/1", 0, 2, ("p",), 1.0), now=100.0)
    roster.heard(WorkerInfo("a/2", 1, 2, ("q",), 1.0), now=100.0)
    assert roster.missing(100.0 + MISSING_AFTER_S) == []
    roster.forget(5.0, now=150.0)  # both gone (a relaunch); the monitor forgets them
    roster.heard(WorkerInfo("b/7", 0, 2, ("p",), 2.0), now=200.0)
    assert roster.missing(200.0 + MISSING_AFTER_S - 1.0) == []  # the split started again
    assert roster.missing(200.0 + MISSING_AFTER_S) == [(1, 2)]
