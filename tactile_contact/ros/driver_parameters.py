"""The ``skin_driver`` node's parameters: name, default, description and range of each.

A table, kept apart from the node so that the node module holds behaviour only;
docs/driver.md and config/skin_driver.yaml mirror it.
"""

from __future__ import annotations

from typing import Any

from tactile_contact.ros import common as cm

# (name, default, description, options for common.declare_parameter); docs/driver.md mirrors it.
# fmt: off
PARAMETERS: tuple[tuple[str, Any, str, dict[str, Any]], ...] = (
    ("autostart", True, "configure and activate at start (no lifecycle manager needed)", {}),
    ("layout", "", "patch layout YAML; empty = the package's config/hexagon_patch.yaml", {}),
    ("patches", cm.STRING_ARRAY_EMPTY, "patches to publish; empty = all of the layout "
     "(of its bus)", {}),
    ("bus", "", "the layout bus this driver serves (its patches); empty = the layout's only "
     "bus", {}),
    ("buses", cm.STRING_ARRAY_EMPTY, "the layout buses this driver serves, each with its own "
     "receive thread, all in one taxel_batches stream (instead of bus)", {}),
    ("channels", cm.STRING_ARRAY_EMPTY, "python-can channel of each of buses (same order); "
     "empty = channel for one bus, else each bus's name (socketcan: can0, can1, ...)", {}),
    ("batch_window_ms", 2.0, "taxel_batches: the readings completed within this long of the "
     "first one not yet published go out in one TaxelBatch (sooner once every patch has one, "
     "or with several buses once its buses are complete and no other is due within it); "
     "0 = each receive's at once", {"unit": "ms", "float_range": (0.0, 100.0)}),
    ("idle_every", 1, "taxel_batches: an untouched patch's readings (every taxel within "
     "idle_counts of its baseline, none in contact, status unchanged) go out every this many "
     "periods; a touched one's every period; 1 = every reading (canbus.idle_gate)",
     {"int_range": (1, 1000)}),
    ("idle_counts", 3.0, "|deviation| within which a taxel is untouched for idle_every",
     {"unit": "8-bit counts", "float_range": (0.0, 255.0)}),
    ("interface", "socketcan", "python-can interface (socketcan, virtual, ...)", {}),
    ("channel", "can0", "python-can channel", {}),
    ("bitrate", 1_000_000, "bit rate for interfaces that set it; 0 = leave as is",
     {"unit": "bit/s", "int_range": (0, 1_000_000)}),
    ("replay_file", "", "candump .log replayed at recorded pace instead of a live bus", {}),
    ("replay_max_gap_s", 1.0, "longer gaps in the replayed log are shortened to this",
     {"unit": "s", "float_range": (0.01, 60.0)}),
    ("accept_class3", False, "also accept class 3 ids (0x3xx, older firmware)", {}),
    ("receive_timeout_s", 0.02, "bus receive timeout (bounds the max-wait check delay)",
     {"unit": "s", "float_range": (0.001, 1.0)}),
    ("reconnect_after_errors", 5, "consecutive bus errors that trigger a reconnect",
     {"int_range": (1, 100_000)}),
    ("reconnect_interval_s", 1.0, "first wait before reopening a failed bus; doubles per failure",
     {"unit": "s", "float_range": (0.01, 60.0)}),
    ("reconnect_max_interval_s", 10.0, "longest wait between attempts to reopen the bus",
     {"unit": "s", "float_range": (0.01, 600.0)}),
    ("bus_filter", True, "bus drops other ids (kernel filter on socketcan, error frames pass "
     "there); false: every frame reaches the driver and is counted by kind", {}),
    ("stamp_source", "can", "header.stamp: CAN receive time or publication time",
     {"choices": ("can", "now")}),
    ("period_ms", 50, "nominal module period (drop estimate; SET_BRD_CFG)",
     {"unit": "ms", "int_range": (1, 255)}),
    ("max_wait_ms", 50.0, "publish a patch this long after its first new module reading",
     {"unit": "ms", "float_range": (1.0, 10_000.0)}),
    ("module_timeout_ms", 500.0, "a module silent this long is not waited for (silent)",
     {"unit": "ms", "float_range": (1.0, 600_000.0)}),
    ("pair_window_ms", 10.0, "largest frame A to frame B gap of one period (below period_ms)",
     {"unit": "ms", "float_range": (0.0, 1000.0)}),
    ("duplicate_window_ms", 5.0, "identical frames closer than this are duplicates",
     {"unit": "ms", "float_range": (0.0, 1000.0)}),
    ("strict_status", False, "reject frames B with reserved status bits set", {}),
    ("farad_per_count", 0.0, "gain of one CDC count; 0 = the layout's sensor value",
     {"unit": "F", "float_range": (0.0, 1e-12)}),
    ("calibration_samples", 20, "unloaded readings averaged at start",
     {"int_range": (1, 100_000)}),
    ("drift_time_constant_s", 20.0, "time constant of drift tracking (no contact)",
     {"unit": "s", "float_range": (0.1, 1e6)}),
    ("contact_on_counts", 3.0, "|deviation| entering contact (freezes drift tracking)",
     {"unit": "8-bit counts", "float_range": (0.1, 255.0)}),
    ("contact_off_counts", 2.0, "|deviation| below which contact may end",
     {"unit": "8-bit counts", "float_range": (0.0, 255.0)}),
    ("release_s", 1.0, "time below contact_off_counts before contact ends",
     {"unit": "s", "float_range": (0.0, 3600.0)}),
    ("release_fraction", 0.25, "also released below this fraction of the peak |deviation|; 0 = off",
     {"float_range": (0.0, 0.99)}),
    ("onset_time_constant_s", 2.0, "onset filter; only faster presses freeze drift tracking",
     {"unit": "s", "float_range": (0.01, 3600.0)}),
    ("freeze_radius_m", 0.012, "taxels this close to a contact are frozen too",
     {"unit": "m", "float_range": (0.0, 1.0)}),
    ("module_freeze", True, "freeze a whole module when one of its taxels is in contact", {}),
    ("max_freeze_s", 300.0, "resume drift tracking after this long frozen; 0 = never",
     {"unit": "s", "float_range": (0.0, 1e6)}),
    ("stuck_timeout_s", 60.0, "unchanged this long = stuck; 0 = never",
     {"unit": "s", "float_range": (0.0, 1e6)}),
    ("dead_timeout_s", 5.0, "reading 0 this long = dead",
     {"unit": "s", "float_range": (0.01, 1e6)}),
    ("tare_window", 10, "readings averaged by ~/tare", {"int_range": (1, 10_000)}),
    ("send_config", False, "send SET_BRD_CFG, SET_TRIANG_CFG, SET_TXMODE on activate", {}),
    ("skin_type", 0, "SET_BRD_CFG skin type", {"int_range": (0, 15)}),
    ("cdc_offset", 0x2200, "SET_TRIANG_CFG CDC offset",
     {"unit": "CDC counts", "int_range": (0, 0xFFFF)}),
    ("diagnostics_period_s", 1.0, "period of /diagnostics",
     {"unit": "s", "float_range": (0.1, 60.0)}),
)
# fmt: on
