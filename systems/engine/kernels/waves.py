"""Level-parallel breadth-first cascade: the waiting list served wave by wave, each wave on all threads.

The breadth-first cascade (kernels.chainmail, ORDER_BREADTH_FIRST) already runs in waves: the grabbed
elements are wave 0, and the elements the sponsors of wave k move are wave k + 1, queued in the order
of (their sponsor's place in wave k, the link's place in the sponsor's row). While wave k is served, an
element that has not moved still has the position it had before the cascade, and the sponsors of wave
k have their final positions; so whether sponsor s would move candidate e, and where to, depends on
nothing else the wave writes.

Which sponsor wins. A candidate that several sponsors of the wave would move is moved by the first of
them in the sequential order: the one earliest in wave k (for one sponsor, a link occurs once). That is
the sponsor the sequential breadth-first cascade uses, because there the candidate is checked against
each sponsor in that order and moves at the first check it fails; it stays within the rule of 5.2.3
(an element moves once, to the nearest point of its box with respect to a neighbour that has already
moved).

How a wave runs. The wave's sponsors are cut into contiguous chunks, one prange iteration each, and
three passes follow; none costs O(N), and nothing is allocated (the winner buffer only grows on the
largest wave so far):

1. claim: every (sponsor i, candidate e) pair whose check moves e lowers claim[e] to i with an atomic
   minimum, so claim[e] ends as the earliest sponsor that moves e, whatever the threads' timing (a
   pair whose e already holds an earlier claim is skipped); each chunk also counts its pairs;
2. move: each chunk finds its pairs with claim[e] == i (its winners), repeats their check on pos
   itself (the same arithmetic on the same inputs, so the same result; only that pair touches e),
   stamps them and lists them in its own stretch of a buffer (as long as its pairs, so it cannot
   overflow; the stretches come from a prefix sum over the chunks' pair counts);
3. place: an exclusive prefix sum over the chunks' winner counts gives each its slice of the next
   wave, into which it copies its list: chunk after chunk, the sequential order.

The serial work between the passes is the two prefix sums over the chunks.

claim[e] is set back when e serves as a sponsor in the next wave (nothing else touches a moved
element's claim), so the array stays ready for the next cascade without a pass over it. Waves with
fewer sponsors than PARALLEL_MIN run the sequential loop on the calling thread: a parallel region
costs more than their work. The result (positions, order, sponsors) is bit for bit the sequential
breadth-first result, for any number of threads.
"""

from __future__ import annotations

import numba
import numpy as np
from numba import get_num_threads, njit, prange, types
from numba.core import cgutils
from numba.extending import intrinsic

from .boxes import start_cascade

#: waves with fewer sponsors than this run on the calling thread
PARALLEL_MIN = 512
#: When a cascade picks this kernel by itself (cascade(..., parallel=None), what bodies do): (threads, elements)
#: steps, each "with at least this many of numba's threads, on meshes of at least this many elements". From
#: soft drags on tet blocks of 10k to 1M elements with 1, 2, 4, 8 and 16 threads on a 16-core machine
#: (tools/bench/crossover.py; figures in docs/chainmail.md): on 1 and 2 threads it lost at every size
#: (0.5-0.7x: the three parallel passes a wave cost more than the extra core gives); it won from 100k on 8
#: and 16 threads (1.5x and 2.1x there, up to 2.4x) and from 300k on 4 (1.15x, 1.4x at 1M). The serial kernel
#: has since become at least 1.4 times faster (its look-ahead ring, rows of sixteen and byte stamps: soft
#: drags from 0.73x to 0.50x of the lean cascade at 100k and from 0.64x to 0.45x at 1M on a 2-core machine),
#: so the steps keep only what still wins clearly with that speed-up taken off the measured one: 16 threads
#: from 100k, 8 from 300k. A 16-core run of the crossover script again would tell how much more it can take.
AUTO_STEPS = ((16, 100_000), (8, 300_000))
#: the least threads and elements of any step: below either, a cascade stays serial without asking further
#: (cascade checks the size first, before asking numba for its thread count)
AUTO_MIN_THREADS = min(t for t, _ in AUTO_STEPS)
AUTO_MIN_ELEMENTS = min(n for _, n in AUTO_STEPS)


def parallel_wins(n_elements: int, threads: int) -> bool:
    """Whether the level-parallel cascade is the faster breadth-first cascade for a mesh of n_elements
    on `threads` threads (the rule cascade(..., parallel=None) follows; see AUTO_STEPS)."""
    if threads < AUTO_MIN_THREADS or n_elements < AUTO_MIN_ELEMENTS:
        return False
    return any(threads >= t and n_elements >= n for t, n in AUTO_STEPS)


#: prange iterations per thread and wave (more smooths out uneven rows, each costs a little)
CHUNKS_PER_THREAD = 4
#: rows of the per-chunk scratch apart (8 rows of 3 float64: no two chunks share a cache line)
_PAD = 8
_NO_CLAIM = np.iinfo(np.int64).max


@intrinsic
def _atomic_min(typingctx, arr, idx, val):
    """arr[idx] = min(arr[idx], val) as one atomic step (int64 array)."""
    if not (isinstance(arr, types.Array) and arr.dtype == types.int64 and arr.ndim == 1):
        return None
    if not (isinstance(idx, types.Integer) and isinstance(val, types.Integer)):
        return None
    sig = types.void(arr, idx, val)

    def codegen(context, builder, signature, args):
        aryty, idxty, valty = signature.args
        ary = context.make_array(aryty)(context, builder, args[0])
        i = context.cast(builder, args[1], idxty, types.intp)
        v = context.cast(builder, args[2], valty, types.int64)
        ptr = cgutils.get_item_pointer(context, builder, aryty, ary, [i])
        builder.atomic_rmw("min", ptr, v, "monotonic")
        return context.get_dummy_value()

    return sig, codegen


@njit(cache=True, inline="always")
def _clamp1(x, base, d, o, am, ax, be):
    """The clamp of boxes.clamp_axis on plain values: (clamped value, whether it was outside)."""
    ad = abs(d)
    if d >= 0.0:
        lo = base + (am * ad - be * o)
        hi = base + (ax * ad + be * o)
    else:
        lo = base - (ax * ad + be * o)
        hi = base - (am * ad - be * o)
    if x < lo:
        return lo, True
    if x > hi:
        return hi, True
    return x, False


@njit(cache=True, inline="always")
def _sponsor(rest, pos, s):
    """The sponsor's rest and current coordinates as float64 scalars, read once per sponsor (axes past D
    read as 0, which leaves every sum of try_move_to unchanged)."""
    dim = pos.shape[1]
    r0 = np.float64(rest[s, 0])
    b0 = np.float64(pos[s, 0])
    r1 = np.float64(rest[s, 1]) if dim > 1 else 0.0
    b1 = np.float64(pos[s, 1]) if dim > 1 else 0.0
    r2 = np.float64(rest[s, 2]) if dim > 2 else 0.0
    b2 = np.float64(pos[s, 2]) if dim > 2 else 0.0
    return r0, r1, r2, b0, b1, b2


@njit(cache=True, inline="always")
def _check(rest, e, sp, am, ax, be, dst, row):
    """boxes.try_move_to with the sponsor's values sp from _sponsor: clamp dst[row] (holding e's
    position) into e's box, True when a stored value changed. The same arithmetic in the same order."""
    dim = dst.shape[1]
    r0, r1, r2, b0, b1, b2 = sp
    d0 = np.float64(rest[e, 0]) - r0
    d1 = np.float64(rest[e, 1]) - r1 if dim > 1 else 0.0
    d2 = np.float64(rest[e, 2]) - r2 if dim > 2 else 0.0
    a0 = abs(d0)
    a1 = abs(d1)
    a2 = abs(d2)
    c, out = _clamp1(np.float64(dst[row, 0]), b0, d0, a1 + a2, am, ax, be)
    moved = False
    if out:
        old = dst[row, 0]
        dst[row, 0] = c
        moved = dst[row, 0] != old
    if dim > 1:
        c, out = _clamp1(np.float64(dst[row, 1]), b1, d1, a0 + a2, am, ax, be)
        if out:
            old = dst[row, 1]
            dst[row, 1] = c
            moved = moved or dst[row, 1] != old
    if dim > 2:
        c, out = _clamp1(np.float64(dst[row, 2]), b2, d2, a0 + a1, am, ax, be)
        if out:
            old = dst[row, 2]
            dst[row, 2] = c
            moved = moved or dst[row, 2] != old
    return moved


@njit(cache=True)
def _serial_wave(lo, hi, nxt, rest, pos, indptr, indices, ealive, eamin, eamax, ebeta, ms, fixed, has_fixed, stamp,
                 gen, out_order, out_sponsor, claim):  # fmt: skip
    """The sequential breadth-first loop over sponsors [lo, hi); appends from nxt, returns the new end."""
    for i in range(lo, hi):
        s = out_order[i]
        sp = _sponsor(rest, pos, s)
        claim[s] = _NO_CLAIM
        for j in range(indptr[s], indptr[s + 1]):
            e = indices[j]
            if stamp[e] == gen or not ealive[j] or (has_fixed and fixed[e]):
                continue
            if _check(rest, e, sp, eamin[j * ms], eamax[j * ms], ebeta[j * ms], pos, e):
                stamp[e] = gen
                out_order[nxt] = e
                out_sponsor[nxt] = s
                nxt += 1
    return nxt


@njit(cache=True, parallel=True)
def _claim_pass(lo, hi, step, chunks, rest, pos, indptr, indices, ealive, eamin, eamax, ebeta, ms, fixed, has_fixed,
                stamp, gen, out_order, claim, scratch, pairs):  # fmt: skip
    dim = pos.shape[1]
    for c in prange(chunks):
        row = c * _PAD
        npairs = 0
        for i in range(lo + c * step, min(lo + (c + 1) * step, hi)):
            s = out_order[i]
            npairs += indptr[s + 1] - indptr[s]
            sp = _sponsor(rest, pos, s)
            claim[s] = _NO_CLAIM  # s moved in the previous wave: its claim is spent (nobody else reads it)
            for j in range(indptr[s], indptr[s + 1]):
                e = indices[j]
                if stamp[e] == gen or not ealive[j] or (has_fixed and fixed[e]):
                    continue  # moved already, cut link, or anchor
                if claim[e] < i:
                    continue  # an earlier sponsor of this wave moves e already (claims only fall)
                for a in range(dim):
                    scratch[row, a] = pos[e, a]
                if _check(rest, e, sp, eamin[j * ms], eamax[j * ms], ebeta[j * ms], scratch, row):
                    _atomic_min(claim, e, i)
        pairs[c * _PAD] = npairs


@njit(cache=True, parallel=True)
def _move_pass(lo, hi, step, chunks, rest, pos, indptr, indices, ealive, eamin, eamax, ebeta, ms, stamp, gen,
               out_order, claim, counts, base, won, won_by):  # fmt: skip
    for c in prange(chunks):
        k = base[c * _PAD]  # this chunk's list: one place per pair of its sponsors, so it cannot overflow
        for i in range(lo + c * step, min(lo + (c + 1) * step, hi)):
            s = out_order[i]
            sp = _sponsor(rest, pos, s)
            for j in range(indptr[s], indptr[s + 1]):
                e = indices[j]
                if claim[e] != i or not ealive[j]:
                    continue
                # only this pair touches e (claim[e] names one sponsor): the check again, now in place
                _check(rest, e, sp, eamin[j * ms], eamax[j * ms], ebeta[j * ms], pos, e)
                stamp[e] = gen
                won[k] = e
                won_by[k] = s
                k += 1
        counts[c * _PAD] = k - base[c * _PAD]


@njit(cache=True, parallel=True)
def _place_pass(chunks, counts, base, won, won_by, out_order, out_sponsor):
    for c in prange(chunks):
        src = base[c * _PAD + 1]  # (the list's start; counts now hold the chunk's first slot)
        dst = counts[c * _PAD]
        for k in range(base[c * _PAD + 2]):
            out_order[dst + k] = won[src + k]
            out_sponsor[dst + k] = won_by[src + k]


@njit(cache=True)
def _waves(rest, pos, indptr, indices, ealive, eamin, eamax, ebeta, ms, grabbed, targets, fixed, has_fixed, stamp,
           gen, out_order, out_sponsor, claim, scratch, counts, base, won, won_by, threads, par_min,
           per_thread):  # fmt: skip
    count = start_cascade(pos, grabbed, targets, fixed, has_fixed, stamp, gen, out_order, out_sponsor)
    if count < 0:
        return count, won, won_by
    lo = 0
    hi = count
    max_chunks = counts.shape[0] // _PAD
    while hi > lo:
        size = hi - lo
        if threads < 2 or size < par_min:
            nxt = _serial_wave(lo, hi, hi, rest, pos, indptr, indices, ealive, eamin, eamax, ebeta, ms, fixed,
                               has_fixed, stamp, gen, out_order, out_sponsor, claim)  # fmt: skip
        else:
            chunks = min(max_chunks, threads * per_thread, size)
            step = (size + chunks - 1) // chunks
            chunks = (size + step - 1) // step
            _claim_pass(lo, hi, step, chunks, rest, pos, indptr, indices, ealive, eamin, eamax, ebeta, ms, fixed,
                        has_fixed, stamp, gen, out_order, claim, scratch, base)  # fmt: skip
            total = 0
            for c in range(chunks):  # each chunk's winner list starts after the pairs of the chunks before
                k = base[c * _PAD]
                base[c * _PAD] = total
                total += k
            if total > won.shape[0]:  # rare: the largest wave so far, the lists grow (kept for later calls)
                won = np.empty(2 * total, np.int64)
                won_by = np.empty(2 * total, np.int64)
            _move_pass(lo, hi, step, chunks, rest, pos, indptr, indices, ealive, eamin, eamax, ebeta, ms, stamp,
                       gen, out_order, claim, counts, base, won, won_by)  # fmt: skip
            nxt = hi
            for c in range(chunks):  # exclusive prefix sum: each chunk's first slot in the next wave
                k = counts[c * _PAD]
                base[c * _PAD + 1] = base[c * _PAD]
                base[c * _PAD + 2] = k
                counts[c * _PAD] = nxt
                nxt += k
            _place_pass(chunks, counts, base, won, won_by, out_order, out_sponsor)
        lo = hi
        hi = nxt
    return hi, won, won_by


class WaveBuffers:
    """Scratch of the level-parallel cascade, kept on a cascade Workspace (made on first use): O(N) claims
    and O(threads) per-chunk scratch, padded against false sharing."""

    def __init__(self, n: int, dim: int, dtype):
        self.claim = np.full(n, _NO_CLAIM, dtype=np.int64)
        chunks = CHUNKS_PER_THREAD * max(numba.config.NUMBA_NUM_THREADS, 1)
        self.scratch = np.empty((chunks * _PAD, dim), dtype=dtype)
        self.counts = np.zeros(chunks * _PAD, dtype=np.int64)
        self.base = np.zeros(chunks * _PAD, dtype=np.int64)
        self.won = np.empty(0, dtype=np.int64)  # the winners of a wave, per chunk (grown on demand)
        self.won_by = np.empty(0, dtype=np.int64)


def cascade_waves(
    rest, pos, indptr, indices, ealive, eamin, eamax, ebeta, ms, grabbed, targets, fixed, has_fixed, stamp, gen, ws
) -> int:
    """The breadth-first cascade, wave by wave on numba's threads (arguments as chainmail's kernels, ws a
    Workspace); returns how many elements moved, or a negative start error code."""
    n, dim = pos.shape
    wb = getattr(ws, "waves", None)
    if wb is None or wb.claim.shape[0] != n or wb.scratch.shape[1] != dim or wb.scratch.dtype != pos.dtype:
        wb = ws.waves = WaveBuffers(n, dim, pos.dtype)
    count, wb.won, wb.won_by = _waves(
        rest, pos, indptr, indices, ealive, eamin, eamax, ebeta, ms, grabbed, targets, fixed, has_fixed, stamp, gen,
        ws.out_order, ws.out_sponsor, wb.claim, wb.scratch, wb.counts, wb.base, wb.won, wb.won_by, get_num_threads(),
        PARALLEL_MIN, CHUNKS_PER_THREAD,
    )  # fmt: skip
    return count
