"""A batch's quiet patch-frames in one compiled call (issue 25).

An idle patch, or a press held still, costs its fusion one compiled pass over the readings
(tactile_contact.inverse._temporal_kernels.quiet_frame); what cost most was the Python around
it, patch by patch (docs/bench/tail.md: 55–57 µs an idle patch-frame in the robot's scene,
against ≈ 10 µs compiled). :class:`QuietBatch` hands every such frame of a TaxelBatch to one
call (``quiet_batch``) over the patches' own arrays, kept in numba typed lists (a slot a
patch, refreshed when the fusion replaces an array), and returns which of them need Python:
a change, an idle scan's pick, a count that differs. The others only count (PatchPipeline.
batch_held); every patch's results, counters and learnt noise stay those of its own path
(test/test_quiet_batch.py).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from tactile_contact.inverse import _temporal_kernels as kern


@dataclass
class _Slot:
    """Where one patch's arrays sit in the typed lists, and which objects they are."""

    index: int
    owner: tuple  # (the fusion, the noise tracker, the permutation) the slot was made for
    window_ok: Any
    q: Any
    sigma: Any
    noise_sigma: Any
    delta: Any  # the kernel's scratch: the frame's δ [m] and taxels used, as it converted them
    ok: Any


def _vector(a: Any, dtype: Any) -> np.ndarray:
    """``a`` itself, checked to be what the typed lists hold (C-contiguous, ``dtype``):
    the kernel changes it in place, so a copy would lose the changes."""
    if not (isinstance(a, np.ndarray) and a.dtype == dtype and a.flags.c_contiguous):
        raise TypeError(f"quiet batch: an array of {a.dtype} not C-contiguous {dtype}")
    return a


class QuietBatch:
    """The typed lists of every served patch's arrays, and the call over a batch's quiet
    frames (:meth:`run`)."""

    def __init__(self, unusable: int) -> None:
        self.unusable = int(unusable)  # the status flags that leave a taxel out
        # numba typed lists (made and changed by compiled calls: kern.list_of, list_add,
        # list_set), None until the first slot; their lengths.
        self.lists: dict[str, Any] = dict.fromkeys(("f1", "i1", "f2", "i2", "b1"))
        self._sizes = dict.fromkeys(self.lists, 0)
        self._warm()
        self._slots: dict[str, _Slot] = {}
        #: Frames that went by the compiled call and needed nothing more, and those that did.
        self.held = 0
        self.rest = 0

    def _slot(self, pipe: Any) -> _Slot:
        """``pipe``'s slot, made or refreshed so that it holds the arrays in use now."""
        fusion, noise = pipe.recon.fusion, pipe.noise
        slot = self._slots.get(pipe.name)
        owner = (fusion, noise, pipe._perm)
        sigma = pipe._noise_seen[1]
        if slot is None or any(a is not b for a, b in zip(slot.owner, owner, strict=True)):
            slot = self._make(pipe, slot)
        window_ok, q = fusion.batch_replaced()
        if slot.window_ok is not window_ok:  # (replaced by a change)
            slot.window_ok = window_ok
            self._put("b1", kern.B1 * slot.index + kern.B1_WINDOW_OK, _vector(window_ok, bool))
        if slot.q is not q:  # (replaced by a re-solve)
            slot.q = q
            self._put("f2", kern.F2 * slot.index + kern.F2_Q, _vector(q, np.float64))
        x = kern.F1 * slot.index
        if slot.sigma is not sigma:
            slot.sigma = sigma
            self._put("f1", x + kern.F1_SIGMA, _vector(sigma, np.float64))
        if slot.noise_sigma is not noise.sigma:
            slot.noise_sigma = noise.sigma
            self._put("f1", x + kern.F1_NOISE_SIGMA, _vector(noise.sigma, np.float64))
        return slot

    def _warm(self) -> None:
        """Load the compiled calls (numba's disk cache) now, on the types a batch brings, not
        in a worker's first batch (≈ 1 s)."""
        f, i, b = np.zeros(1), np.zeros(1, np.int64), np.zeros(1, bool)
        kinds = (f, i, f.reshape(1, 1), i.reshape(1, 1), b)  # (the order of self.lists)
        for a in kinds:
            kern.list_set(kern.list_of(a), 0, a)
            kern.list_add(kern.list_of(a), a)
        none, no = np.zeros(0, np.int64), np.zeros(0, bool)
        kern.quiet_batch(
            np.frombuffer(bytes(4), np.float32),  # (a message's arrays: read-only)
            np.frombuffer(bytes(1), np.uint8),
            none,
            none,
            none,
            no,
            no,
            none,
            self.unusable,
            *(kern.list_of(a) for a in kinds),
            np.zeros((0, 5), np.int64),
        )

    def _put(self, name: str, i: int, a: np.ndarray) -> None:
        """Entry ``i`` of typed list ``name`` set to ``a`` (appended at its end)."""
        lst = self.lists[name]
        if lst is None:
            self.lists[name] = kern.list_of(a)
        elif i < self._sizes[name]:
            kern.list_set(lst, i, a)
            return
        else:
            kern.list_add(lst, a)
        self._sizes[name] += 1

    def _make(self, pipe: Any, old: _Slot | None) -> _Slot:
        fusion, noise = pipe.recon.fusion, pipe.noise
        a = fusion.batch_arrays()
        k = len(a["total"])
        var, m4, alpha, spike = noise.step_arrays()
        f64 = np.float64
        f1 = [None] * kern.F1
        f1[kern.F1_CONVERT] = _vector(pipe._convert, f64)
        f1[kern.F1_DELTA] = np.zeros(k)
        f1[kern.F1_SIGMA] = _vector(pipe._noise_seen[1], f64)
        f1[kern.F1_TOTAL] = _vector(a["total"], f64)
        f1[kern.F1_STATE] = _vector(a["state"], f64)
        f1[kern.F1_LOCAL] = _vector(a["local"], f64)
        f1[kern.F1_LIMITS] = _vector(a["limits"], f64)
        f1[kern.F1_TRIGGER] = _vector(a["trigger"], f64)
        f1[kern.F1_SPARE] = _vector(a["spare"], f64)
        f1[kern.F1_NOISE_SIGMA] = _vector(noise.sigma, f64)
        f1[kern.F1_NOISE_VAR] = _vector(var, f64)
        f1[kern.F1_NOISE_M4] = _vector(m4, f64)
        f1[kern.F1_NOISE_RATE] = np.array([alpha, spike], dtype=f64)
        i1 = [_vector(pipe._perm, np.int64), _vector(a["windows"], np.int64)]
        f2 = [_vector(a["buf"], f64), _vector(a["q"], f64), _vector(a["wsum"], f64)]
        b1 = [np.zeros(k, dtype=bool), _vector(a["window_ok"], bool)]
        nbr = _vector(a["nbr"], np.int64)
        index = len(self._slots) if old is None else old.index
        for name, new, width in (
            ("f1", f1, kern.F1),
            ("i1", i1, kern.I1),
            ("f2", f2, kern.F2),
            ("b1", b1, kern.B1),
            ("i2", [nbr], 1),
        ):
            for j, v in enumerate(new):
                self._put(name, width * index + j, v)
        slot = _Slot(
            index,
            (fusion, noise, pipe._perm),
            a["window_ok"],
            a["q"],
            pipe._noise_seen[1],
            noise.sigma,
            f1[kern.F1_DELTA],
            b1[kern.B1_OK],
        )
        self._slots[pipe.name] = slot
        return slot

    def run(self, view: Any, items: list, rows: Any, add_row: Any) -> None:
        """A batch's frames: ``items`` (pipe, stamp [ns], first row, end row, batch_ready's
        answer) in the batch's order; those ready go by one compiled call, the others by
        PatchPipeline.frame; each one's row appended to ``rows`` (``add_row``) in order."""
        t0 = time.perf_counter()
        ready = [it for it in items if it[4] >= 0]
        n = len(ready)
        answers: list = []
        held: list[_Slot] = []
        share, now = (0.0, 0.0, 0.0), 0.0
        if n:
            starts, ends, scan, idle, expect = [], [], [], [], []
            for pipe, _, a, b, sc in ready:
                held.append(self._slot(pipe))
                starts.append(a)
                ends.append(b)
                scan.append(sc)
                result = pipe.recon.fusion.result
                idle.append(not result.in_contact)
                expect.append(result.taxels_used)
            slots = np.array([slot.index for slot in held], dtype=np.int64)
            out = np.empty((n, 5), dtype=np.int64)
            t1 = time.perf_counter()
            kern.quiet_batch(
                view.delta_c,
                view.status,
                np.array(starts, dtype=np.int64),
                np.array(ends, dtype=np.int64),
                slots,
                np.array(scan, dtype=bool),
                np.array(idle, dtype=bool),
                np.array(expect, dtype=np.int64),
                self.unusable,
                *self.lists.values(),
                out,
            )
            t2 = time.perf_counter()
            share = ((t1 - t0) / n, (t2 - t1) / n, 0.0)
            now = time.monotonic()
            answers = out.tolist()
        j = 0
        for pipe, stamp, a, b, sc in items:
            if sc < 0:
                result = pipe.frame(
                    stamp, view.taxel_ids[a:b], view.delta_c[a:b], view.status[a:b], contact=False
                )
            else:
                code, w, valid, fast, learnt = answers[j]
                slot = held[j]
                j += 1
                if fast:
                    self.held += 1
                    result = pipe.batch_held(stamp, bool(learnt), now, share)
                elif code < 0:  # (a reading not finite: the full path says so)
                    self.rest += 1
                    result = pipe.frame(
                        stamp,
                        view.taxel_ids[a:b],
                        view.delta_c[a:b],
                        view.status[a:b],
                        contact=False,
                    )
                else:
                    self.rest += 1
                    result = pipe.batch_rest(stamp, code, w, valid, slot.delta, slot.ok, t0)
            add_row(rows, pipe, stamp, result)
