import numba
import numpy as np
import pytest

from mcverify import _uniform_stream as stream

B = stream.STREAM_BLOCK


def _numpy_rows(seq, start, m, k):
    """Rows ``start .. start + m`` of the stream as numpy draws them: block b from
    ``Generator(PCG64(SeedSequence(entropy, spawn_key + (b,)))).random()``."""
    first, last = start // B, -(-(start + m) // B)
    u = np.empty(((last - first) * B, k))
    for b in range(first, last):
        child = np.random.SeedSequence(seq.entropy, spawn_key=seq.spawn_key + (b,))
        r = b - first
        np.random.Generator(np.random.PCG64(child)).random(out=u[r * B:(r + 1) * B])
    return u[:m]


@pytest.mark.parametrize("m", [1, 7, B - 1, B, B + 1, 3 * B, 4 * B - 1, 4 * B, 4 * B + 5,
                               7 * B + 3, 9 * B])
@pytest.mark.parametrize("k", [1, 2, 3])
def test_the_numba_stream_is_numpys_pcg64_number_for_number(m, k):
    """Every count of rows (partial blocks, block counts that are and are not multiples
    of the four run in lockstep), every row width: numpy's numbers, bit for bit."""
    seq = np.random.SeedSequence(2024).spawn(3)[2]
    u = stream.rows(seq, 0, np.empty((m, k)))
    assert np.array_equal(u, _numpy_rows(seq, 0, m, k))


def test_rows_from_a_later_block_and_any_thread_count(numba_threads):
    """A chunk starting at block 5 is the stream's rows there; one thread or two give the
    same numbers."""
    seq = np.random.SeedSequence(7)
    want = _numpy_rows(seq, 5 * B, 6 * B + 11, 2)
    for t in sorted({1, min(2, numba.config.NUMBA_NUM_THREADS)}):
        numba_threads(t)
        assert np.array_equal(stream.rows(seq, 5 * B, np.empty((6 * B + 11, 2))), want)


def test_different_seeds_and_blocks_differ():
    a = stream.rows(np.random.SeedSequence(1), 0, np.empty((2 * B, 1)))
    b = stream.rows(np.random.SeedSequence(2), 0, np.empty((2 * B, 1)))
    assert not np.array_equal(a, b)
    assert not np.array_equal(a[:B], a[B:])
    assert 0.0 <= a.min() and a.max() < 1.0


def _numpy_states(seq, first, count):
    out = np.empty((count, 4), dtype=np.uint64)
    for r in range(count):
        child = np.random.SeedSequence(seq.entropy, spawn_key=seq.spawn_key + (first + r,))
        st = np.random.PCG64(child).state["state"]
        s, inc = st["state"], st["inc"]
        out[r] = (s >> 64, s & (2 ** 64 - 1), inc >> 64, inc & (2 ** 64 - 1))
    return out


@pytest.mark.parametrize("seq", [
    np.random.SeedSequence(0).spawn(2)[1],            # the checks' streams: a spawned child
    np.random.SeedSequence(12345),                    # no spawn key: the run padded to 4 words
    np.random.SeedSequence(2 ** 64 + 1, spawn_key=(7,)),
    np.random.SeedSequence(2 ** 127 + 3, spawn_key=(1, 2 ** 40)),   # multi-word key values
    np.random.SeedSequence([1, 2, 2 ** 35]),          # entropy given as a sequence
    np.random.SeedSequence(5, spawn_key=(0, 1, 2, 3, 4, 5)),
    np.random.SeedSequence(),                         # entropy from the OS (128 bits)
], ids=["child", "plain", "key", "wide-key", "sequence", "long-key", "os"])
@pytest.mark.parametrize("first,count", [(0, 20), (2 ** 31, 3), (2 ** 32 - 2, 2),
                                         (2 ** 32 - 1, 3), (10, 0)])
def test_block_states_are_numpys_seeding(seq, first, count):
    """``block_states`` computes numpy's SeedSequence mixing and PCG64 seeding itself:
    the very states numpy gives each block, for spawned and plain sequences, entropy of
    one to four words or a sequence, spawn keys of big values; block indexes past 2^32
    (two key words) take numpy's own path."""
    assert np.array_equal(stream.block_states(seq, first, count),
                          _numpy_states(seq, first, count))
