"""The simulator's firmware shift and 8-bit saturation, as the boards have them: values checked
against the firmware formula written out here with Python integers, the host's configuration
commands (made by the driver's codec) sent over a python-can virtual bus, and the driver's
stream reading the frames back (ΔC within one count of the shift, saturated channels flagged).
"""

from __future__ import annotations

import time
import uuid

import can
import numpy as np
import pytest

from tactile_contact.canbus import codec
from tactile_contact.model.modules import ROBOSKIN12, place_channels
from tactile_contact.model.sensor import SensorParams, compression_to_delta_c
from tactile_contact.sim.simulator import (
    Indentation,
    SkinSimulator,
    saturating_delta_c,
    write_log,
)

MODULES = [(0, 0), (0, 1), (2, 5)]
XY = np.vstack([place_channels(ROBOSKIN12, (0.03 * i, 0.0), 0.0) for i in range(len(MODULES))])


class Bump:
    """δ = k·F·(exp(−r²/s²) − 0.3·exp(−r²/(3s)²)) [m]: a press with a negative ring."""

    def __init__(self, k: float = 60e-6, s: float = 3e-3) -> None:
        self.k, self.s = k, s

    def compression(self, indenter, force, center_xy):
        r2 = np.sum((XY - np.asarray(center_xy)) ** 2, axis=1)
        return self.k * force * (np.exp(-r2 / self.s**2) - 0.3 * np.exp(-r2 / (3 * self.s) ** 2))


def firmware_value(cdc: int, no_load: int, shift: int) -> tuple[int, bool]:
    """The board's 8-bit value, written out: noLoad − (cdc >> shift) (Python's >> floors, as
    the firmware's arithmetic shift does), clipped to 0..255, and whether it clipped."""
    raw = no_load - (cdc >> shift)
    return min(max(raw, 0), 255), not 0 <= raw <= 255


def held(force: float) -> Indentation:
    return Indentation.press("sphere", force, tuple(XY[3]), start_s=0.0, ramp_s=0.05, hold_s=1.0)


@pytest.mark.parametrize("shift", [0, 1, 2, 3])
def test_values_follow_the_firmware_formula_at_each_shift(shift: int) -> None:
    sensor = SensorParams(shift=shift)
    sim = SkinSimulator(MODULES, Bump(), sensor=sensor, noise_cdc=3.0, seed=shift)
    for p in sim.periods(held(2.0), 0.5):
        tr = p.truth
        # The same CDC counts the simulator drew: its noise is reproduced from its seed.
        for i in range(len(tr.values)):
            cdc_real = tr.delta_c[i] / sensor.farad_per_count
            # The value is that of a whole CDC count within 6 σ of the noiseless one.
            ok = [
                firmware_value(c, 240, shift)
                for c in range(int(np.floor(cdc_real - 18)), int(np.ceil(cdc_real + 18)) + 1)
            ]
            assert (int(tr.values[i]), bool(tr.out_of_range[i])) in ok
    # One count is 2**shift CDC counts: ΔC from the value is within a count of the truth.
    count = sensor.value_count_farad
    dc = (240 - tr.values.astype(float)) * count
    inside = ~tr.out_of_range
    assert np.all(np.abs(dc - tr.delta_c)[inside] <= count + 6 * 3.0 * sensor.farad_per_count)


def test_saturation_at_both_ends_is_clipped_and_flagged() -> None:
    """Shift 0: a hard press clips at 0 under the indenter (compression beyond noLoad counts)
    and its ring clips at 255 (a bulge beyond 255 − noLoad = 15 counts)."""
    sensor = SensorParams(shift=0)
    hi, lo = saturating_delta_c(sensor)
    assert hi == pytest.approx(240 * sensor.farad_per_count)
    assert lo == pytest.approx(-15 * sensor.farad_per_count)
    model = Bump(k=400e-6)
    sim = SkinSimulator(MODULES, model, sensor=sensor, noise_cdc=0.0)
    tr = sim.period(held(2.0), 0.5).truth
    over, under = tr.delta_c > hi, tr.delta_c < lo
    assert over.any() and under.any()
    assert np.all(tr.values[over] == 0) and np.all(tr.values[under] == 255)
    assert np.array_equal(tr.out_of_range, over | under)
    # The same press at shift 3 stays in range.
    sim3 = SkinSimulator(MODULES, model, sensor=SensorParams(shift=3), noise_cdc=0.0)
    tr3 = sim3.period(held(2.0), 0.5).truth
    assert not tr3.out_of_range.any()
    # The limits in compression: shift 2 reads up to ≈ 1.1 mm and down to ≈ −0.17 mm.
    s2 = SensorParams()
    hi2, lo2 = saturating_delta_c(s2)
    for dc, want in ((hi2, 1.12e-3), (lo2, -0.172e-3)):
        d = s2.delta_c_to_compression(dc)
        assert float(d) == pytest.approx(want, rel=0.01)
        assert float(compression_to_delta_c(d, s2.thickness, s2.epsilon_r, s2.area)) == (
            pytest.approx(dc)
        )


def test_host_commands_over_a_virtual_bus_set_shift_and_no_load() -> None:
    """The driver's configuration commands (codec) reach the simulator over a virtual bus and
    change what the addressed triangles send; other boards, other triangles and non-commands
    are left alone."""
    channel = f"shift-{uuid.uuid4().hex}"
    sim = SkinSimulator(MODULES, Bump(), noise_cdc=0.0)
    with (
        can.Bus(interface="virtual", channel=channel) as host,
        can.Bus(interface="virtual", channel=channel) as board,
    ):
        for cmd in (
            codec.set_board_config(0, 0, 50, 230),
            codec.set_triangle_config(0, 1, 3, 3, True, 0),  # board 0, triangles 1..3
            codec.set_triangle_config(7, 0, 15, 0, True, 0),  # a board not simulated
        ):
            host.send(cmd.to_message())
        host.send(can.Message(arbitration_id=0x401, data=bytes(8), is_extended_id=False))
        applied = []
        while (m := board.recv(timeout=0.5)) is not None:
            applied.append(sim.apply_command(m))
    assert applied == [True, True, False, False]
    assert sim.shift.tolist() == [2, 3, 2] and sim.no_load.tolist() == [230, 230, 240]
    tr = sim.period(held(2.0), 0.5).truth
    sensor = SensorParams()
    cdc = np.rint(tr.delta_c / sensor.farad_per_count).astype(int)
    for i, (no_load, shift) in enumerate(((230, 2), (230, 3), (240, 2))):
        for c in range(12 * i, 12 * i + 12):
            assert (int(tr.values[c]), bool(tr.out_of_range[c])) == firmware_value(
                int(cdc[c]), no_load, shift
            )
    # A disabled triangle sends nothing.
    sim.apply_command(codec.set_triangle_config(2, 5, 5, 2, False, 0).to_message())
    ids = {m.arbitration_id for m in sim.period(held(2.0), 0.5).messages}
    assert ids == {codec.skin_id(0, 0), codec.skin_id(0, 1)}


@pytest.mark.parametrize("shift", [0, 3])
def test_driver_stream_reads_the_shift_back_and_flags_saturation(tmp_path, shift: int) -> None:
    """Simulator at ``shift`` → candump log → the driver's SkinStream configured with the same
    shift: held ΔC within a count (2**shift CDC counts) of the truth; channels at a clipping
    limit (0 or 255, clipped or not) carry the stream's saturated status, and those the module
    clipped its out-of-range status."""
    from tactile_contact.canbus.baseline import (
        STATUS_OUT_OF_RANGE,
        STATUS_SATURATED,
        BaselineConfig,
    )
    from tactile_contact.canbus.stream import SkinStream
    from tactile_contact.model.layout import parse_layout

    sensor = SensorParams(shift=shift)
    sim = SkinSimulator(MODULES, Bump(k=150e-6), sensor=sensor, noise_cdc=1.0, seed=3)
    ind = Indentation.press("sphere", 2.0, tuple(XY[3]), start_s=3.0, ramp_s=0.2, hold_s=2.0)
    truths = write_log(tmp_path / "s.log", sim.periods(ind, 5.0))
    mods = [
        {"type": "roboskin12", "board": b, "triangle": t, "position": [0.03 * i, 0.0]}
        for i, (b, t) in enumerate(MODULES)
    ]
    doc = {
        "schema_version": 1,
        "patches": [
            {"name": "p", "frame_id": "p", "modules": mods, "sensor": {"shift": shift}},
        ],
    }
    patch = parse_layout(doc).patches[0]
    stream = SkinStream([patch], baseline=BaselineConfig(), period_s=0.05)
    frames = [f for m in can.LogReader(tmp_path / "s.log") for f in stream.feed(m, now=m.timestamp)]
    assert len(frames) == len(truths)
    late = [(f, t) for f, t in zip(frames, truths, strict=True) if 3.5 <= t.t < 4.8]
    count = sensor.value_count_farad
    for f, t in late:
        status = np.frombuffer(f.status, np.uint8)
        at_limit = (t.values == 0) | (t.values == 255)
        assert np.array_equal((status & STATUS_SATURATED) != 0, at_limit)
        assert np.array_equal((status & STATUS_OUT_OF_RANGE) != 0, t.out_of_range)
        ok = ~at_limit
        assert np.all(np.abs(np.asarray(f.delta_c)[ok] - t.delta_c[ok]) <= 1.5 * count + 5e-15)
    clipped = np.any([t.out_of_range for _, t in late], axis=0)
    assert clipped.any() == (shift == 0)


@pytest.mark.ros
def test_simulator_node_takes_the_hosts_shift_from_the_bus(ros_context) -> None:
    """The skin_simulator node, pressing on a virtual bus: a SET_TRIANG_CFG with shift 3 sent
    by the host (the driver's codec) to the pressed triangle changes what it sends: its frames
    on the bus then carry the firmware's values at shift 3, the other triangles' at shift 2."""
    from pathlib import Path

    from rclpy.parameter import Parameter

    from tactile_contact.canbus.codec import FRAME_A, decode_frame
    from tactile_contact.ros.skin_simulator import SkinSimulatorNode

    layout = Path(__file__).resolve().parents[1] / "config" / "hexagon_patch.yaml"
    channel = f"shift-node-{uuid.uuid4().hex}"
    params = {
        "layout": str(layout),
        "interface": "virtual",
        "channel": channel,
        "scenario": "press",
        "start_delay_s": 0.0,
        "cycle_s": 30.0,
        "period_ms": 20,
        "noise_cdc": 0.0,
        "force_n": 3.0,
    }
    overrides = [Parameter(k, value=v) for k, v in params.items()]
    with can.Bus(interface="virtual", channel=channel) as host:
        node = SkinSimulatorNode(context=ros_context, parameter_overrides=overrides)
        try:
            held = node.sim.period(node.indentation, 1.0).truth.delta_c.reshape(-1, 12)
            pressed = node.sim.modules[int(np.argmax(held.max(axis=1)))][1]
            host.send(codec.set_triangle_config(0, pressed, pressed, 3, True, 0).to_message())
            deadline = time.monotonic() + 5.0
            while node.commands_applied == 0 and time.monotonic() < deadline:
                time.sleep(0.02)
            assert node.commands_applied == 1
            assert node.sim.shift.tolist() == [3 if t == pressed else 2 for _, t in MODS6]
            time.sleep(0.8)  # past the 0.5 s ramp: the press held
            while host.recv(timeout=0.0) is not None:  # frames sent before: dropped
                pass
            time.sleep(0.1)
            frames = [decode_frame(m.arbitration_id, bytes(m.data)) for m in _drain(host)]
            tr = node.sim.period(node.indentation, 1.0).truth  # held: the same values
        finally:
            node.destroy_node()
    got: dict[tuple[int, int], bytes] = {}
    for f in frames:
        got[(f.triangle, f.kind)] = f.values
    assert len(got) == 12, "frames A and B of all six triangles"
    cdc = np.rint(tr.delta_c / SensorParams().farad_per_count).astype(int)
    for m, (_, tri) in enumerate(node.sim.modules):
        shift = 3 if tri == pressed else 2
        want = [firmware_value(int(c), 240, shift)[0] for c in cdc[12 * m : 12 * m + 12]]
        sent = list(got[(tri, FRAME_A)]) + list(got[(tri, 0xC0)])
        assert sent == want, (tri, sent, want)
    assert max(240 - v for v in got[(pressed, FRAME_A)] + got[(pressed, 0xC0)]) >= 5


MODS6 = [(0, t) for t in range(6)]  # the hexagon's modules: board 0, triangles 0..5


def _drain(bus: can.BusABC, window_s: float = 0.5) -> list[can.Message]:
    """The frames received within ``window_s`` [s] (a live simulator never falls silent: reading
    until a gap hung once the node's 20 ms periods came closer together than the gap)."""
    out = []
    end = time.monotonic() + window_s
    while (left := end - time.monotonic()) > 0:
        if (m := bus.recv(timeout=min(left, 0.05))) is not None:
            out.append(m)
    return out
