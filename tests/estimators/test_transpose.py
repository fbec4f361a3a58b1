"""The front ends' row <-> column moves (``estimators._transpose``) move values exactly."""

import numpy as np
import pytest
from numba import njit

from estimators import _transpose as tr

LANES = tr.LANES


def _movers(k, streaming=False):
    load = getattr(tr, f"load_rows{k}")
    store = getattr(tr, f"stream_rows{k}" if streaming else f"store_rows{k}")

    @njit
    def to_columns(rows, i, columns, t):
        load(rows, i, columns, t)

    @njit
    def to_rows(columns, t, rows, i):
        store(columns, t, rows, i)
        tr.store_fence()

    return to_columns, to_rows


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("k", [1, 2, 3])
def test_rows_to_columns_and_back_move_every_value_to_its_place(k, dtype):
    """Distinct values (so a swapped lane or coordinate shows), a source offset ``i`` and
    a scratch offset ``t`` that are not multiples of the lane count, and neighbours left
    as they were: nothing outside the ``LANES`` rows and columns is written."""
    to_columns, to_rows = _movers(k)
    rows = (np.arange(40 * k, dtype=np.float64).reshape(40, k) * np.pi).astype(dtype)
    columns = np.full((k, 32), -1.0)
    i, t = 5, 3
    to_columns(rows, i, columns, t)
    want = np.full((k, 32), -1.0)
    want[:, t:t + LANES] = rows[i:i + LANES].T.astype(np.float64)
    assert np.array_equal(columns, want)

    columns = np.random.default_rng(k).normal(size=(k, 32)) * 1e3
    out = np.full((40, k), 7.0, dtype=dtype)
    to_rows(columns, t, out, i)
    want = np.full((40, k), 7.0, dtype=dtype)
    want[i:i + LANES] = columns[:, t:t + LANES].T.astype(dtype)     # rounded to nearest
    assert np.array_equal(out, want)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("k", [1, 2, 3])
def test_streaming_stores_write_what_plain_stores_write(k, dtype):
    """``stream_rows{k}`` into rows that start on a 64-byte line (as the front ends lay
    out their large outputs), at every group of ``LANES`` rows: the same values as the
    plain stores, nothing written past the group."""
    _, plain = _movers(k)
    _, streaming = _movers(k, streaming=True)
    columns = np.random.default_rng(k).normal(size=(k, 8 * LANES))
    n = 4 * LANES + 3
    raw = np.zeros(n * k * np.dtype(dtype).itemsize + 64, np.uint8)
    skip = -raw.ctypes.data % 64
    got = raw[skip:skip + n * k * np.dtype(dtype).itemsize].view(dtype).reshape(n, k)
    assert got.ctypes.data % 64 == 0
    want = np.full((n, k), 7.0, dtype)
    got[:] = 7.0
    for g in range(4):
        plain(columns, 2 * LANES * g, want, LANES * g)
        streaming(columns, 2 * LANES * g, got, LANES * g)
    assert np.array_equal(got, want)
    moved = np.concatenate([columns[:, 2 * LANES * g:2 * LANES * g + LANES].T for g in range(4)])
    assert np.array_equal(got[:4 * LANES], moved.astype(dtype))
    assert np.all(got[4 * LANES:] == 7.0)


def test_the_movers_refuse_what_they_cannot_move():
    """Rows must be a 2-D C-contiguous float array, the scratch 2-D float64: anything
    else is a typing error at compile time, not a wrong read."""
    from numba.core.errors import TypingError

    to_columns, _ = _movers(2)
    with pytest.raises(TypingError):
        to_columns(np.zeros((16, 2), np.int64), 0, np.zeros((2, 8)), 0)
    with pytest.raises(TypingError):
        to_columns(np.zeros((2, 16)).T, 0, np.zeros((2, 8)), 0)
    with pytest.raises(TypingError):
        to_columns(np.zeros((16, 2)), 0, np.zeros((2, 8), np.float32), 0)
