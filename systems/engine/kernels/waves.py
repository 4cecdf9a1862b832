"""Level-parallel breadth-first cascade: the waiting list served wave by wave, each wave on all threads.

The breadth-first cascade (kernels.chainmail, ORDER_BREADTH_FIRST) already runs in waves: the grabbed
elements are wave 0, and the elements the sponsors of wave k move are wave k + 1, queued in the order
of (their sponsor's place in wave k, the link's place in the sponsor's row). While wave k is served, an
element that has not moved still has the position it had before the cascade, and the sponsors of wave
k have their final positions; so whether sponsor s would move candidate e, and where to, depends on
nothing else the wave writes. This kernel therefore checks all of a wave's (sponsor, candidate) pairs
in parallel and only then applies the moves.

Which sponsor wins. A candidate that several sponsors of the wave would move is moved by the first of
them in the sequential order: the one earliest in wave k (for one sponsor, a link occurs once). That is
the sponsor the sequential breadth-first cascade uses, because there the candidate is checked against
each sponsor in that order and moves at the first check it fails; it stays within the rule of 5.2.3
(an element moves once, to the nearest point of its box with respect to a neighbour that has already
moved). The result (positions, order, sponsors) is bit for bit the sequential breadth-first result, for
any number of threads: every decision depends only on values no thread writes during the wave, and the
moves are applied in the sequential order. Small waves run on one thread (a parallel region costs more
than their work).
"""

from __future__ import annotations

import numpy as np
from numba import get_num_threads, njit, prange

from .boxes import start_cascade, try_move_to

#: waves with fewer candidate pairs than this run on the calling thread
PARALLEL_MIN = 8192


@njit(cache=True)
def _fill(s_lo, s_hi, out_order, indptr, indices, ealive, fixed, has_fixed, stamp, gen, cnt, pair_entry, pair_rank):
    """Slots of sponsors [s_lo, s_hi): one per row entry, from offset cnt[i] (so the slots follow the
    sequential order); the entry's index for a candidate (unmoved, live, free neighbour), else -1."""
    for i in range(s_lo, s_hi):
        s = out_order[i]
        k = cnt[i]
        for j in range(indptr[s], indptr[s + 1]):
            e = indices[j]
            if stamp[e] != gen and ealive[j] and not (has_fixed and fixed[e]):
                pair_entry[k] = j
            else:
                pair_entry[k] = -1
            pair_rank[k] = i
            k += 1


@njit(cache=True)
def _decide(
    p_lo,
    p_hi,
    second,
    rest,
    pos,
    indptr,
    indices,
    ealive,
    eamin,
    eamax,
    ebeta,
    ms,
    out_order,
    stamp,
    gen,
    rank,
    wave_lo,
    pair_entry,
    pair_rank,
    first,
    seen,
    tag,
    win,
    buf,
):
    """Pairs [p_lo, p_hi): whether the sponsor moves the candidate first (win[p]; buf[p] the new
    position). Pass 1 (second=False) decides the pairs that are their candidate's first in the sequential
    order; pass 2 the later pairs of candidates whose first sponsor left them in place (seen[e] == -tag),
    by checking the earlier sponsors of the wave again. Reads only what the wave does not write."""
    dim = pos.shape[1]
    tmp = np.empty((1, dim), dtype=pos.dtype)
    for p in range(p_lo, p_hi):
        j = pair_entry[p]
        if j < 0:  # not a candidate
            win[p] = False
            continue
        e = indices[j]
        if not second:
            if not first[p]:
                win[p] = False
                continue
        elif first[p] or seen[e] != -tag:
            continue
        i = pair_rank[p]
        s = out_order[i]
        for a in range(dim):
            buf[p, a] = pos[e, a]
        if not try_move_to(rest, pos, e, s, eamin[j * ms], eamax[j * ms], ebeta[j * ms], buf, p):
            win[p] = False
            if not second:
                seen[e] = -tag  # left in place by its first sponsor: the later ones decide (pass 2)
            continue
        if not second:
            win[p] = True
            continue
        wins = True
        for jj in range(indptr[e], indptr[e + 1]):
            s2 = indices[jj]
            # an earlier sponsor of this wave, over a live link: would it have moved e first?
            if stamp[s2] != gen or not ealive[jj] or rank[s2] < wave_lo or rank[s2] >= i:
                continue
            for a in range(dim):
                tmp[0, a] = pos[e, a]
            if try_move_to(rest, pos, e, s2, eamin[jj * ms], eamax[jj * ms], ebeta[jj * ms], tmp, 0):
                wins = False
                break
        win[p] = wins


@njit(cache=True, parallel=True)
def _fill_par(
    s_lo, s_hi, out_order, indptr, indices, ealive, fixed, has_fixed, stamp, gen, cnt, pair_entry, pair_rank, chunks
):
    step = (s_hi - s_lo + chunks - 1) // chunks
    for c in prange(chunks):
        lo = s_lo + c * step
        _fill(
            lo,
            min(lo + step, s_hi),
            out_order,
            indptr,
            indices,
            ealive,
            fixed,
            has_fixed,
            stamp,
            gen,
            cnt,
            pair_entry,
            pair_rank,
        )


@njit(cache=True, parallel=True)
def _decide_par(
    npairs,
    second,
    rest,
    pos,
    indptr,
    indices,
    ealive,
    eamin,
    eamax,
    ebeta,
    ms,
    out_order,
    stamp,
    gen,
    rank,
    wave_lo,
    pair_entry,
    pair_rank,
    first,
    seen,
    tag,
    win,
    buf,
    chunks,
):
    step = (npairs + chunks - 1) // chunks
    for c in prange(chunks):
        lo = c * step
        _decide(
            lo,
            min(lo + step, npairs),
            second,
            rest,
            pos,
            indptr,
            indices,
            ealive,
            eamin,
            eamax,
            ebeta,
            ms,
            out_order,
            stamp,
            gen,
            rank,
            wave_lo,
            pair_entry,
            pair_rank,
            first,
            seen,
            tag,
            win,
            buf,
        )


@njit(cache=True)
def _waves(
    rest,
    pos,
    indptr,
    indices,
    ealive,
    eamin,
    eamax,
    ebeta,
    ms,
    grabbed,
    targets,
    fixed,
    has_fixed,
    stamp,
    gen,
    out_order,
    out_sponsor,
    rank,
    cnt,
    pair_entry,
    pair_rank,
    first,
    seen,
    tag,
    win,
    buf,
    threads,
    par_min,
):
    count = start_cascade(pos, grabbed, targets, fixed, has_fixed, stamp, gen, out_order, out_sponsor)
    if count < 0:
        return count, tag
    for i in range(count):
        rank[out_order[i]] = i
    wave_lo = 0
    wave_hi = count
    chunks = 4 * threads
    while wave_hi > wave_lo:
        # one slot per row entry of the wave's sponsors, at offsets in the sequential order
        cnt[wave_lo] = 0
        for i in range(wave_lo, wave_hi):
            s = out_order[i]
            cnt[i + 1] = cnt[i] + indptr[s + 1] - indptr[s]
        npairs = cnt[wave_hi]
        if threads > 1 and npairs >= par_min:
            _fill_par(
                wave_lo, wave_hi, out_order, indptr, indices, ealive, fixed, has_fixed, stamp, gen, cnt, pair_entry,
                pair_rank, chunks,
            )  # fmt: skip
        else:
            _fill(
                wave_lo, wave_hi, out_order, indptr, indices, ealive, fixed, has_fixed, stamp, gen, cnt, pair_entry,
                pair_rank,
            )  # fmt: skip
        # which pairs come first for their candidate (serial: one flag per pair)
        tag += 1
        retry = False
        for p in range(npairs):
            if pair_entry[p] < 0:
                continue
            e = indices[pair_entry[p]]
            if seen[e] == tag or seen[e] == -tag:
                first[p] = False
            else:
                seen[e] = tag
                first[p] = True
        par = threads > 1 and npairs >= par_min
        for second in (False, True):
            if second and not retry:
                break
            if par:
                _decide_par(
                    npairs, second, rest, pos, indptr, indices, ealive, eamin, eamax, ebeta, ms, out_order, stamp,
                    gen, rank, wave_lo, pair_entry, pair_rank, first, seen, tag, win, buf, chunks,
                )  # fmt: skip
            else:
                _decide(
                    0, npairs, second, rest, pos, indptr, indices, ealive, eamin, eamax, ebeta, ms, out_order, stamp,
                    gen, rank, wave_lo, pair_entry, pair_rank, first, seen, tag, win, buf,
                )  # fmt: skip
            if not second:
                for p in range(npairs):
                    if pair_entry[p] >= 0 and first[p] and not win[p]:
                        retry = True
                        break
        # apply the moves in the sequential order: the next wave
        next_hi = wave_hi
        dim = pos.shape[1]
        for p in range(npairs):
            if win[p]:  # (never for an empty slot)
                e = indices[pair_entry[p]]
                for a in range(dim):
                    pos[e, a] = buf[p, a]
                stamp[e] = gen
                rank[e] = next_hi
                out_order[next_hi] = e
                out_sponsor[next_hi] = out_order[pair_rank[p]]
                next_hi += 1
        wave_lo = wave_hi
        wave_hi = next_hi
    return wave_hi, tag


class WaveBuffers:
    """Scratch of the level-parallel cascade, kept on a cascade Workspace (made on first use)."""

    def __init__(self, n: int, entries: int, dim: int, dtype):
        self.rank = np.zeros(n, dtype=np.int64)
        self.cnt = np.zeros(n + 1, dtype=np.int64)
        self.pair_entry = np.empty(max(entries, 1), dtype=np.int64)
        self.pair_rank = np.empty(max(entries, 1), dtype=np.int64)
        self.win = np.zeros(max(entries, 1), dtype=np.bool_)
        self.first = np.zeros(max(entries, 1), dtype=np.bool_)
        self.seen = np.zeros(n, dtype=np.int64)  # == +-tag: a candidate of the current wave
        self.tag = 0
        self.buf = np.empty((max(entries, 1), dim), dtype=dtype)


def cascade_waves(
    rest, pos, indptr, indices, ealive, eamin, eamax, ebeta, ms, grabbed, targets, fixed, has_fixed, stamp, gen, ws
) -> int:
    """The breadth-first cascade, wave by wave on numba's threads (arguments as chainmail's kernels, ws a
    Workspace); returns how many elements moved, or a negative start error code."""
    n, dim = pos.shape
    entries = indices.shape[0]
    wb = getattr(ws, "waves", None)
    if wb is None or wb.rank.shape[0] != n or wb.pair_entry.shape[0] < entries or wb.buf.dtype != pos.dtype:
        wb = ws.waves = WaveBuffers(n, entries, dim, pos.dtype)
    count, wb.tag = _waves(
        rest, pos, indptr, indices, ealive, eamin, eamax, ebeta, ms, grabbed, targets, fixed, has_fixed, stamp, gen,
        ws.out_order, ws.out_sponsor, wb.rank, wb.cnt, wb.pair_entry, wb.pair_rank, wb.first, wb.seen, wb.tag, wb.win,
        wb.buf, get_num_threads(), PARALLEL_MIN,
    )  # fmt: skip
    return count
