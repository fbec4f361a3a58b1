"""The warps' array front ends (``estimators._vectorize``): streamed outputs and the
fused ``with_pdf`` give the bits of the plain calls."""

import numpy as np
import pytest

from estimators import _vectorize
from estimators.warps import WARPS
from test_warps import FLOAT32_SHAPES


def _streamed_and_not(monkeypatch, dtype, names):
    u = np.random.default_rng(11).random((2 * 512 + 13, 3)).astype(dtype)

    def run():
        outs = []
        for name in names:
            w = WARPS[name]
            x = w.sample(u[:, :w.sample_dim], *w.defaults)
            outs += [x, w.pdf(x, *w.defaults)]
            if w.invert is not None:
                outs.append(w.invert(x, *w.defaults))
        return outs

    monkeypatch.setattr(_vectorize, "STREAM_BYTES", 1 << 62)
    plain = run()
    monkeypatch.setattr(_vectorize, "STREAM_BYTES", 0)
    streamed = run()
    for a, b in zip(plain, streamed):
        assert a.dtype == b.dtype == dtype and np.array_equal(a, b)
        assert b.ctypes.data % 64 == 0 and b.flags.writeable
        assert b.ndim == 1 or b.flags.c_contiguous


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_front_ends_give_the_same_bits_streaming_or_not(monkeypatch, dtype):
    """Every warp's sample, pdf and inverse with every output streamed (the threshold
    set to 0 bytes) against the same calls with none streamed (the threshold above the
    outputs), at a row count that leaves a partial group and a partial block; a streamed
    output starts on a 64-byte line, is C-contiguous and writable. float32: the warps
    of ``FLOAT32_SHAPES`` (every shape of the loop template; the float32 inverse loops of
    all sixteen warps took 5 minutes to compile on a 2-core Zen 1), every warp in the
    slow run."""
    _streamed_and_not(monkeypatch, dtype,
                      sorted(WARPS) if dtype == np.float64 else FLOAT32_SHAPES)


@pytest.mark.slow
def test_every_warps_float32_front_ends_give_the_same_bits_streaming_or_not(monkeypatch):
    _streamed_and_not(monkeypatch, np.float32, sorted(WARPS))


#: Warps whose fused loops the default run compiles (each loop takes ~3 s to compile on
#: a new machine): every shape of loop (1 -> 1 with two parameters, 2 -> 2, 2 -> 3, a
#: kernel inlined into the loop, a density that divides and calls ``fast_exp``); every
#: warp, in both dtypes, in the slow run.
_DEFAULT_WARPS = {np.float64: ("uniform_interval", "bilinear", "cosine_hemisphere",
                               "beckmann", "ggx_vndf"),
                  np.float32: ("cosine_hemisphere", "beckmann")}


def _check_with_pdf(monkeypatch, dtype, streamed, names):
    monkeypatch.setattr(_vectorize, "STREAM_BYTES", 0 if streamed else 1 << 62)
    u = np.random.default_rng(21).random((512 + 8 * 3 + 5, 3)).astype(dtype)
    u[:4, 0] = [0.0, 0.5, np.nextafter(dtype(1), dtype(0)), 1e-30]
    for name in names:
        w = WARPS[name]
        settings = [w.defaults] + [tuple(lo + (hi - lo) * f for lo, hi in w.ranges)
                                   for f in (0.05, 0.95)]
        for params in settings:
            if name == "ggx_vndf":              # (wx, wy, wz) must stay a unit vector
                params = (params[0],) + w.defaults[1:]
            ui = u[:, :w.sample_dim]
            x, pdf = w.sample.with_pdf(ui, *params)
            want_x = w.sample(ui, *params)
            want_pdf = w.pdf(want_x, *params)
            assert x.dtype == pdf.dtype == dtype and pdf.shape == (len(u),), name
            assert np.array_equal(x, want_x), (name, params)
            assert np.array_equal(pdf, want_pdf, equal_nan=True), (name, params)


@pytest.mark.parametrize("streamed", [False, True])
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_with_pdf_gives_the_bits_of_sample_then_pdf(monkeypatch, dtype, streamed):
    """Every warp's ``sample.with_pdf(u)`` against ``x = sample(u)``, ``pdf(x)``: the same
    points and densities bit for bit (float32: the density of the point as stored), at
    the default parameters and near both ends of each one's range, streamed or not; the
    outputs' dtype is the input's and the pdf is 1-D. The warps of ``_DEFAULT_WARPS``
    here, every warp in the slow run."""
    _check_with_pdf(monkeypatch, dtype, streamed, _DEFAULT_WARPS[dtype])


@pytest.mark.slow
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_with_pdf_gives_the_bits_of_sample_then_pdf_for_every_warp(monkeypatch, dtype):
    _check_with_pdf(monkeypatch, dtype, True, sorted(WARPS))


def test_with_pdf_checks_what_sample_checks():
    """Parameters and shapes are checked as the sampler checks them, the message naming
    ``sample_X.with_pdf``."""
    f = WARPS["beckmann"].sample.with_pdf
    with pytest.raises(ValueError, match=r"sample_beckmann\.with_pdf: takes 1 parameter"):
        f(np.zeros((4, 2)))
    with pytest.raises(ValueError, match=r"sample_beckmann\.with_pdf: alpha=-1\.0"):
        f(np.zeros((4, 2)), -1.0)
    with pytest.raises(ValueError, match=r"shape \(n, 2\)"):
        f(np.zeros((4, 3)), 0.3)
