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

A fault stays with its patch, as in the batch's loop without this call (contact_batches.
full_frame): a patch whose Python step raises gets a FAILED row, its ``internal_errors``
counted and said; the other patches' rows are what they would be. A compiled call that
raises (a typed list of the wrong type, say) is said once, counted (``errors``), its typed
lists are made again on the next batch, and the batch's frames it did not finish take the
full path.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from tactile_contact.inverse import _temporal_kernels as kern
from tactile_contact.ros.contact_batches import full_frame

# The column of the call's answers (the table from OUT_CODE on) that says a patch was
# reached, and the answer columns of a row as given (OUT_FAST -1: not reached).
_FAST = kern.OUT_FAST - kern.OUT_CODE
_NOT_REACHED = (0, 0, 0, -1, 0)


@dataclass
class _Slot:
    """Where one patch's arrays sit in the typed lists, and which objects they are."""

    index: int
    # the fusion, the noise tracker, the permutation the slot was made for
    fusion: Any
    noise: Any
    perm: Any
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


def _text(exc: Exception, most: int = 300) -> str:
    """``exc`` in one line of at most ``most`` characters (numba's typing errors run to
    dozens of lines)."""
    text = " ".join(f"{type(exc).__name__}: {exc}".split())
    return text if len(text) <= most else text[: most - 1] + "…"


class QuietBatch:
    """The typed lists of every served patch's arrays, and the call over a batch's quiet
    frames (:meth:`run`)."""

    def __init__(self, unusable: int, log: Callable[[str], None] | None = None) -> None:
        self.unusable = int(unusable)  # the status flags that leave a taxel out
        self._log = log  # (an error's one line: the node's logger)
        # numba typed lists (made and changed by compiled calls: kern.list_of, list_add,
        # list_set), None until the first slot; their lengths.
        self.lists: dict[str, Any] = dict.fromkeys(("f1", "i1", "f2", "i2", "b1"))
        self._sizes = dict.fromkeys(self.lists, 0)
        self._warm()
        self._slots: dict[str, _Slot] = {}
        #: Frames that went by the compiled call and needed nothing more, and those that did.
        self.held = 0
        self.rest = 0
        #: Faults of the compiled path (a compiled call that raised, a slot that could not be
        #: made: their frames taken by the full path), the last one's text.
        self.errors = 0
        self.last_error = ""

    def _slot(self, pipe: Any) -> _Slot:
        """``pipe``'s slot, made or refreshed so that it holds the arrays in use now."""
        fusion, noise = pipe.recon.fusion, pipe.noise
        slot = self._slots.get(pipe.name)
        sigma = pipe._noise_seen[1]
        if (
            slot is None
            or slot.fusion is not fusion
            or slot.noise is not noise
            or slot.perm is not pipe._perm
        ):
            slot = self._make(pipe, slot)
        window_ok, q = fusion.batch_replaced()
        # (each array put in its list before the slot notes it: one refused is tried again)
        if slot.window_ok is not window_ok:  # (replaced by a change)
            self._put("b1", kern.B1 * slot.index + kern.B1_WINDOW_OK, _vector(window_ok, bool))
            slot.window_ok = window_ok
        if slot.q is not q:  # (replaced by a re-solve)
            self._put("f2", kern.F2 * slot.index + kern.F2_Q, _vector(q, np.float64))
            slot.q = q
        x = kern.F1 * slot.index
        if slot.sigma is not sigma:
            self._put("f1", x + kern.F1_SIGMA, _vector(sigma, np.float64))
            slot.sigma = sigma
        if slot.noise_sigma is not noise.sigma:
            self._put("f1", x + kern.F1_NOISE_SIGMA, _vector(noise.sigma, np.float64))
            slot.noise_sigma = noise.sigma
        return slot

    def _forget(self) -> None:
        """Every slot and typed list dropped: made again from the patches' arrays by the
        next batch (after a compiled call that raised: the lists may be what made it)."""
        self.lists = dict.fromkeys(self.lists)
        self._sizes = dict.fromkeys(self.lists, 0)
        self._slots = {}

    def _warm(self) -> None:
        """Load the compiled calls (numba's disk cache) now, on the types a batch brings, not
        in a worker's first batch (≈ 1 s)."""
        f, i, b = np.zeros(1), np.zeros(1, np.int64), np.zeros(1, bool)
        kinds = (f, i, f.reshape(1, 1), i.reshape(1, 1), b)  # (the order of self.lists)
        for a in kinds:
            kern.list_set(kern.list_of(a), 0, a)
            kern.list_add(kern.list_of(a), a)
        kern.quiet_batch(
            np.frombuffer(bytes(4), np.float32),  # (a message's arrays: read-only)
            np.frombuffer(bytes(1), np.uint8),
            self.unusable,
            np.zeros((0, kern.TABLE), np.int64),
            *(kern.list_of(a) for a in kinds),
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
            fusion,
            noise,
            pipe._perm,
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
        PatchPipeline.frame; each one's row appended to ``rows`` (``add_row``) in order.

        A frame whose Python raises: its row FAILED, the error the patch's
        (PatchPipeline.internal_error), the others unchanged. A slot that cannot be made
        (an array of an unforeseen type): that frame by the full path. A compiled call that
        raises: said, counted, the frames it did not finish by the full path."""
        t0 = time.perf_counter()
        at = []  # each item's row in the call's table (-1: not in the call)
        held: list[_Slot] = []
        flat: list = []  # the table's rows one after the other (kern.IN_*, then OUT_*)
        for pipe, _, a, b, sc in items:
            if sc < 0:
                at.append(-1)
                continue
            try:
                slot = self._slot(pipe)
                result = pipe.recon.fusion.result
                row = (a, b, slot.index, sc, not result.in_contact, result.taxels_used)
            except Exception as exc:
                self.fault(f"patch {pipe.name}'s slot", exc)
                at.append(-1)
                continue
            at.append(len(held))
            held.append(slot)
            flat += row
            flat += _NOT_REACHED
        n = len(held)
        answers: list = []
        share, now = (0.0, 0.0, 0.0), 0.0
        if n:
            table = np.array(flat, dtype=np.int64).reshape(n, kern.TABLE)
            t1 = time.perf_counter()
            try:
                kern.quiet_batch(
                    view.delta_c, view.status, self.unusable, table, *self.lists.values()
                )
            except Exception as exc:
                # The patches it finished keep their answers; the one it stopped in (which
                # may have taken part of the frame: an error inside the call, not one of its
                # arguments' types) and those after it (untouched) take the full path.
                self.fault("the compiled call", exc, n)
                self._forget()
            t2 = time.perf_counter()
            share = ((t1 - t0) / n, (t2 - t1) / n, 0.0)
            now = time.monotonic()
            answers = table[:, kern.OUT_CODE :].tolist()
        for (pipe, stamp, a, b, _), j in zip(items, at, strict=True):
            if j < 0 or answers[j][_FAST] < 0:
                add_row(rows, pipe, stamp, full_frame(pipe, stamp, view, a, b))
                continue
            code, w, valid, fast, learnt = answers[j]
            try:
                if fast:
                    self.held += 1
                    result = pipe.batch_held(stamp, learnt != 0, now, share)
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
                    slot = held[j]
                    result = pipe.batch_rest(stamp, code, w, valid, slot.delta, slot.ok, t0)
            except Exception as exc:
                if not pipe.node.context.ok():
                    raise
                pipe.internal_error(exc)
                result = None
            add_row(rows, pipe, stamp, result)

    def fault(self, where: str, exc: Exception, frames: int = 1) -> None:
        """A fault of the batch's compiled path (``where`` raised ``exc``): counted, logged
        and kept for /diagnostics; its ``frames`` go by the full path."""
        self.errors += 1
        self.last_error = (
            f"quiet batch: {where} raised {_text(exc)}; {frames} frame(s) by the full path"
        )
        if self._log is not None:
            self._log(self.last_error)
