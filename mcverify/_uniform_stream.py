"""The checks' seeded uniform numbers, drawn by numba on every core.

A stream is cut into blocks of ``STREAM_BLOCK`` rows; block b is the output of numpy's
``Generator(PCG64(SeedSequence(entropy, spawn_key + (b,)))).random()``, so the numbers
do not depend on how the stream is cut into chunks or on the thread count. The blocks'
generators are seeded as numpy seeds them (``block_states``: SeedSequence's mixing and
PCG64's seeding, computed here); their output is computed by ``fill``, a numba kernel
that runs PCG64's step (a 128-bit multiply-add) and its XSL-RR output as numpy's C code
does. Both bit for bit, tested against numpy.

Why not numpy itself: its generators ran on a thread pool beside the checks' numba
kernels, and on two cores the two thread teams starved each other (the uniforms of a
1e6-row chunk took 3.5-4.8 ms there, 2.35 alone). ``fill`` runs on the threads of the
checks' other loops (``mcnumba.threads``), and steps four blocks' generators in
lockstep, which hides the multiply's latency: 1.1 ns a number on one thread, against
numpy's 1.8-2.0.
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

from mcnumba.threads import LOOP, run_ranges

#: Rows of one seeded block of a stream.
STREAM_BLOCK = 1 << 16
#: PCG64's multiplier (numpy's ``PCG_DEFAULT_MULTIPLIER_128``), high and low halves.
_MUL_HI = 0x2360ED051FC65DA4
_MUL_LO = 0x4385DF649FCCF645
_MASK64 = (1 << 64) - 1


@intrinsic
def _mul128(typingctx, a_hi, a_lo, b_hi, b_lo):
    """(high, low) halves of ``a · b mod 2^128``, ``a`` and ``b`` given by their 64-bit
    halves: LLVM's i128 multiply (three machine multiplies)."""
    sig = types.UniTuple(types.uint64, 2)(types.uint64, types.uint64, types.uint64,
                                          types.uint64)

    def codegen(context, builder, signature, args):
        i128 = ir.IntType(128)
        ah, al, bh, bl = (builder.zext(v, i128) for v in args)
        shift = ir.Constant(i128, 64)
        a = builder.or_(builder.shl(ah, shift), al)
        b = builder.or_(builder.shl(bh, shift), bl)
        r = builder.mul(a, b)
        lo = builder.trunc(r, ir.IntType(64))
        hi = builder.trunc(builder.lshr(r, shift), ir.IntType(64))
        return context.make_tuple(builder, signature.return_type, (hi, lo))

    return sig, codegen


@njit(cache=True, inline="always")
def _step(s_hi, s_lo, i_hi, i_lo):
    """One PCG64 step: the new state ``s · MUL + inc`` and its output as a double in
    [0, 1) (XSL-RR: the halves' xor rotated by the top 6 bits; then 53 bits), as numpy's
    ``next_double``."""
    h, lo = _mul128(s_hi, s_lo, np.uint64(_MUL_HI), np.uint64(_MUL_LO))
    lo2 = lo + i_lo
    h = h + i_hi + np.uint64(lo2 < lo)
    x = h ^ lo2
    rot = h >> np.uint64(58)
    v = (x >> rot) | (x << ((np.uint64(64) - rot) & np.uint64(63)))
    return h, lo2, np.float64(v >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@njit(cache=True, inline="always")
def _run(st, b, out, lo, hi):
    """Block ``b``'s generator (state row ``st[b]``) fills ``out[lo:hi]``; the state is
    written back."""
    s_hi, s_lo, i_hi, i_lo = st[b, 0], st[b, 1], st[b, 2], st[b, 3]
    for i in range(lo, hi):
        s_hi, s_lo, out[i] = _step(s_hi, s_lo, i_hi, i_lo)
    st[b, 0], st[b, 1] = s_hi, s_lo


@njit(**LOOP)
def _fill_groups(states, block_len, out, g0, g1):
    """``fill`` for the groups of four blocks ``g0`` to ``g1``."""
    n = out.shape[0]
    nb = states.shape[0]
    for g in range(g0, g1):
        b = 4 * g
        starts = (b * block_len, (b + 1) * block_len, (b + 2) * block_len,
                  (b + 3) * block_len)
        common = 0
        if b + 3 < nb:     # four blocks: lockstep over the shortest (only the last is short)
            common = min(block_len, n - starts[3])
            a0, a1, a2, a3 = states[b, 0], states[b, 1], states[b, 2], states[b, 3]
            b0, b1, b2, b3 = states[b + 1, 0], states[b + 1, 1], states[b + 1, 2], states[b + 1, 3]
            c0, c1, c2, c3 = states[b + 2, 0], states[b + 2, 1], states[b + 2, 2], states[b + 2, 3]
            d0, d1, d2, d3 = states[b + 3, 0], states[b + 3, 1], states[b + 3, 2], states[b + 3, 3]
            for i in range(common):
                a0, a1, out[starts[0] + i] = _step(a0, a1, a2, a3)
                b0, b1, out[starts[1] + i] = _step(b0, b1, b2, b3)
                c0, c1, out[starts[2] + i] = _step(c0, c1, c2, c3)
                d0, d1, out[starts[3] + i] = _step(d0, d1, d2, d3)
            states[b, 0], states[b, 1] = a0, a1
            states[b + 1, 0], states[b + 1, 1] = b0, b1
            states[b + 2, 0], states[b + 2, 1] = c0, c1
            states[b + 3, 0], states[b + 3, 1] = d0, d1
        for j in range(min(4, nb - b)):       # what lockstep left (all of a short group)
            lo = starts[j]
            _run(states, b + j, out, lo + common, min(lo + block_len, n))


def fill(states, block_len, out):
    """``out`` (flat) from the generators ``states`` (n_blocks, 4: state high, low,
    increment high, low; consumed), ``block_len`` numbers each (the last block takes
    what is left). Groups of four blocks run in lockstep, a range of groups a thread
    (``mcnumba.threads``; a serial ``nogil`` loop compiles in about half the time of a
    ``prange`` one); each block's numbers are its generator's sequence whatever the
    grouping."""
    run_ranges(_fill_groups, (states.shape[0] + 3) // 4, states, block_len, out, grain=1)


# numpy's SeedSequence (numpy/random/bit_generator.pyx): its hash constants and pool size.
_INIT_A, _MULT_A, _INIT_B, _MULT_B = 0x43B0D7E5, 0x931E8875, 0x8B51F9DD, 0x58F38DED
_MIX_L, _MIX_R = 0xCA01F9DD, 0x4973F715
_POOL = 4
_M32 = np.uint64(0xFFFFFFFF)


@njit(cache=True, inline="always")
def _hashmix(value, h):
    """SeedSequence's ``hashmix``: the word ``value`` hashed with the running constant
    ``h``, which steps too (32-bit arithmetic in 64-bit registers)."""
    value = (value ^ h) & _M32
    h = (h * np.uint64(_MULT_A)) & _M32
    value = (value * h) & _M32
    return value ^ (value >> np.uint64(16)), h


@njit(cache=True, inline="always")
def _mix(x, y):
    r = (np.uint64(_MIX_L) * x - np.uint64(_MIX_R) * y) & _M32
    return r ^ (r >> np.uint64(16))


@njit(cache=True)
def _seeded_states(prefix, first, out):
    """``out[r]``: the PCG64 state (high, low, increment high, low) that numpy seeds from
    ``SeedSequence`` whose assembled entropy words are ``prefix`` (at least ``_POOL``
    words) then the block index ``first + r`` (one 32-bit word): its pool
    (``mix_entropy``), four 64-bit words of ``generate_state``, then PCG64's ``srandom``
    (state 0, step, add the seed, step). The prefix is mixed once; each block mixes in
    its last word from there."""
    base = np.empty(_POOL, np.uint64)
    h0 = np.uint64(_INIT_A)
    for i in range(_POOL):
        base[i], h0 = _hashmix(prefix[i], h0)
    for src in range(_POOL):
        for dst in range(_POOL):
            if src != dst:
                v, h0 = _hashmix(base[src], h0)
                base[dst] = _mix(base[dst], v)
    for src in range(_POOL, prefix.shape[0]):
        for dst in range(_POOL):
            v, h0 = _hashmix(prefix[src], h0)
            base[dst] = _mix(base[dst], v)
    mixer = np.empty(_POOL, np.uint64)
    words = np.empty(2 * _POOL, np.uint64)
    for r in range(out.shape[0]):
        last, h = np.uint64(first + r), h0
        for dst in range(_POOL):
            v, h = _hashmix(last, h)
            mixer[dst] = _mix(base[dst], v)
        h = np.uint64(_INIT_B)
        for i in range(2 * _POOL):
            v = (mixer[i % _POOL] ^ h) & _M32
            h = (h * np.uint64(_MULT_B)) & _M32
            v = (v * h) & _M32
            words[i] = v ^ (v >> np.uint64(16))
        seed_hi = words[0] | (words[1] << np.uint64(32))
        seed_lo = words[2] | (words[3] << np.uint64(32))
        seq_hi = words[4] | (words[5] << np.uint64(32))
        seq_lo = words[6] | (words[7] << np.uint64(32))
        i_hi = (seq_hi << np.uint64(1)) | (seq_lo >> np.uint64(63))    # inc = seq·2 + 1
        i_lo = (seq_lo << np.uint64(1)) | np.uint64(1)
        s_lo = i_lo + seed_lo                                         # step from 0, + seed
        s_hi = i_hi + seed_hi + np.uint64(s_lo < i_lo)
        h2, lo = _mul128(s_hi, s_lo, np.uint64(_MUL_HI), np.uint64(_MUL_LO))   # step
        s_lo = lo + i_lo
        s_hi = h2 + i_hi + np.uint64(s_lo < lo)
        out[r, 0], out[r, 1], out[r, 2], out[r, 3] = s_hi, s_lo, i_hi, i_lo


def _words(x) -> list[int] | None:
    """numpy's ``_coerce_to_uint32_array`` of an entropy or spawn-key value: a
    non-negative int's 32-bit words, least significant first (0 is one word); a
    sequence's values' words in turn. None for anything else (numpy's path is taken)."""
    if isinstance(x, (int, np.integer)) and not isinstance(x, bool) and x >= 0:
        v = int(x)
        out = [v & 0xFFFFFFFF]
        v >>= 32
        while v:
            out.append(v & 0xFFFFFFFF)
            v >>= 32
        return out
    if isinstance(x, (list, tuple, np.ndarray)):
        out = []
        for v in x:
            w = _words(v)
            if w is None:
                return None
            out += w
        return out
    return None


def block_states(seq: np.random.SeedSequence, first: int, count: int) -> np.ndarray:
    """PCG64 states (count, 4) of blocks ``first .. first + count`` of the stream ``seq``,
    as numpy seeds ``PCG64(SeedSequence(seq.entropy, seq.spawn_key + (b,)))``: computed
    by ``_seeded_states`` from the assembled entropy (numpy's own objects cost 33 µs a
    block, 0.6 ms of a repeated 1e6-point check; tested equal to them)."""
    out = np.empty((count, 4), dtype=np.uint64)
    run, spawn = _words(seq.entropy), _words(tuple(seq.spawn_key))
    if run is None or spawn is None or seq.pool_size != _POOL or first + count > 1 << 32:
        for r in range(count):
            child = np.random.SeedSequence(seq.entropy, spawn_key=seq.spawn_key + (first + r,))
            st = np.random.PCG64(child).state["state"]
            s, inc = st["state"], st["inc"]
            out[r] = (s >> 64, s & _MASK64, inc >> 64, inc & _MASK64)
        return out
    run += [0] * (_POOL - len(run))          # a spawn key follows: the run padded to the pool
    if count:
        _seeded_states(np.array(run + spawn, dtype=np.uint64), first, out)
    return out


def rows(seq: np.random.SeedSequence, start: int, u: np.ndarray) -> np.ndarray:
    """Fill ``u`` (C-contiguous float64, (m, k)) with rows ``start .. start + m`` of the
    stream ``seq``; ``start`` is a multiple of ``STREAM_BLOCK``."""
    m = u.shape[0]
    if m:
        nb = -(-m // STREAM_BLOCK)
        fill(block_states(seq, start // STREAM_BLOCK, nb), STREAM_BLOCK * u.shape[1],
             u.reshape(-1))
    return u
