"""Subjects written in PyTorch or JAX, whose callables return their own tensors: each
check reads them as numpy reads them. torch and jax are not imported (CI has neither):
each test's stand-in reproduces the library's behaviour that the test is about."""

import numpy as np
import pytest

import mcverify as mv


class _GradTensor:
    """A torch tensor with ``requires_grad=True`` as numpy meets it: ``np.asarray``
    raises torch's RuntimeError until ``.detach()`` (torch 2.13 raises this one)."""

    def __init__(self, a, grad=True):
        self._a, self._grad = np.asarray(a), grad

    def __array__(self, dtype=None, copy=None):
        if self._grad:
            raise RuntimeError("Can't call numpy() on Tensor that requires grad. Use "
                               "tensor.detach().numpy() instead.")
        return self._a if dtype is None else self._a.astype(dtype)

    def detach(self):
        return _GradTensor(self._a, grad=False)

    def cpu(self):
        return self

    def __len__(self):
        return len(self._a)


def _grad(f):
    return lambda *a: _GradTensor(f(*a))


def _sample(u):
    return np.sqrt(u)


def _pdf(x):
    return 4.0 * x[:, 0] * x[:, 1]


_EST = np.pi * np.sin(np.random.default_rng(1).random(2000) * np.pi)
_IMG = np.random.default_rng(2).random((4, 4))

_CALLS = {
    "sampler-points": lambda t: mv.check_sampler(t(_sample), _pdf, "square", n_samples=4000),
    "sampler-pdf": lambda t: mv.check_sampler(_sample, t(_pdf), "square", n_samples=4000),
    "pdf-consistency": lambda t: mv.check_pdf_consistency(
        lambda u: (t(_sample)(u), t(lambda u: _pdf(_sample(u)))(u)), t(_pdf),
        sample_dim=2, n_samples=500),
    "inverse": lambda t: mv.check_inverse(t(_sample), t(np.square), 2, n_samples=500),
    "stability": lambda t: mv.check_stability(t(_sample), "square", sample_dim=2,
                                              pdf=t(_pdf), max_examples=20),
    "same-distribution": lambda t: mv.check_same_distribution(
        t(_sample), _sample, "square", n_samples=2000),
    "unbiased": lambda t: mv.check_unbiased(t(lambda: _EST)(), 2.0),
    "unbiased-batches": lambda t: mv.check_unbiased(
        t(lambda b: _EST[b * 500:(b + 1) * 500]), 2.0, batches=4),
    "variance": lambda t: mv.check_variance(t(lambda: np.full(100, 2.0))()),
    "convergence": lambda t: mv.check_convergence(
        t(lambda n, s: np.random.default_rng(s).random(n).mean()), 0.5,
        ns=(64, 256, 1024), n_seeds=8),
    "images": lambda t: mv.compare_images(
        t(lambda: _IMG)(), _IMG, test_var=t(lambda: _IMG)(), ref_var=_IMG,
        test_n=16, ref_n=16),
}


@pytest.mark.parametrize("check", list(_CALLS), ids=list(_CALLS))
def test_a_tensor_that_requires_grad_is_read_detached(check):
    """A differentiable renderer's sampler, pdf or estimate returning a torch tensor
    with ``requires_grad=True``: every check raised torch's bare "Can't call numpy() on
    Tensor that requires grad" from inside mcverify (an outside review). Its values are
    read, detached, with the verdict numpy's arrays get."""
    with pytest.raises(RuntimeError, match="requires grad"):
        np.asarray(_GradTensor([1.0]))      # the stand-in fails as torch does
    r = _CALLS[check](_grad)
    plain = _CALLS[check](lambda f: f)
    assert r.passed and plain.passed
    assert r.p_value == plain.p_value and r.statistic == plain.statistic


def _torch_sqrt(t):
    """``torch.sqrt`` as it refuses a numpy array (torch 2.13's words)."""
    if isinstance(t, np.ndarray):
        raise TypeError("sqrt(): argument 'input' (position 1) must be Tensor, not "
                        "numpy.ndarray")
    return t.sqrt()


_TORCH_ONLY = {
    # u.clamp is a tensor's method; numpy's AttributeError is the one torch users meet
    "sampler-method": lambda: mv.check_sampler(lambda u: u.clamp(0.0, 1.0), _pdf,
                                               "square", n_samples=2000),
    "sampler-function": lambda: mv.check_sampler(_torch_sqrt, _pdf, "square",
                                                 n_samples=2000),
    "pdf": lambda: mv.check_sampler(_sample, lambda x: 4.0 * _torch_sqrt(x).prod(1),
                                    "square", n_samples=2000),
    "pdf-consistency": lambda: mv.check_pdf_consistency(
        lambda u: (_sample(u), _pdf(_sample(u))), lambda x: _torch_sqrt(x), sample_dim=2,
        n_samples=100),
    "inverse": lambda: mv.check_inverse(_sample, lambda x: x.square(), 2, n_samples=100),
}


@pytest.mark.parametrize("check", list(_TORCH_ONLY), ids=list(_TORCH_ONLY))
def test_a_function_of_torch_tensors_is_told_to_wrap_u(check):
    """A sampler, pdf or inverse written for torch tensors, given the numpy array every
    check passes, raised "'numpy.ndarray' object has no attribute 'clamp'" or torch's
    "must be Tensor, not numpy.ndarray" and nothing else (an outside review): its own
    error still, with a note of what mcverify passed and how to wrap it."""
    with pytest.raises((AttributeError, TypeError), match="numpy.ndarray") as e:
        _TORCH_ONLY[check]()
    # the note names the callable to wrap: "sample" for a pdf's lived (a mutation review)
    name = {"sampler-method": "sample", "sampler-function": "sample",
            "inverse": "inverse"}.get(check, "pdf")
    assert f"lambda a: {name}(torch.from_numpy(a))" in "".join(getattr(e.value, "__notes__", ()))


def test_stability_tells_a_function_of_torch_tensors_to_wrap_u():
    r = mv.check_stability(_torch_sqrt, "square", sample_dim=2, max_examples=10)
    assert not r.passed and "sample(torch.from_numpy(a))" in r.failures[0]


class _JaxArray:
    """A JAX ``Array`` as numpy meets it: read through ``__array__``, no Python number
    (``jnp.float32(0.5)`` is a 0-d one); ``numbers.Real`` does not know it."""

    def __init__(self, a):
        self._a = np.asarray(a)

    def __array__(self, dtype=None, copy=None):
        return self._a if dtype is None else self._a.astype(dtype)


@pytest.mark.parametrize("wrap", [_JaxArray, _GradTensor], ids=["jax", "torch-grad"])
def test_a_0d_array_is_a_real_argument(wrap):
    """``expected=jnp.float32(0.5)`` (a 0-d JAX Array) or a 0-d torch tensor was refused
    as "must be a real number" (an outside review); it is its number, a float32 one
    standing for half its ulp as ``np.float32(0.5)`` does."""
    x = np.full(1000, 0.5, dtype=np.float32)
    for expected in (np.float32(0.5), np.float64(0.5)):
        r = mv.check_unbiased(x, wrap(expected))
        assert r.to_dict() | {"seconds": 0} == mv.check_unbiased(x, expected).to_dict() | {
            "seconds": 0}
    assert mv.check_convergence(lambda n, s: np.random.default_rng(s).random(n).mean(),
                                wrap(0.5), ns=(64, 256, 1024), n_seeds=8).passed
    assert mv.check_variance(np.full(10, 2.0), wrap(0.0)).passed
    with pytest.raises(mv.InvalidArgument, match=r"must be a real number"):
        mv.check_unbiased(x, wrap([0.5]))       # one element of an array stays refused


@pytest.mark.parametrize("wrap", [_JaxArray, _GradTensor], ids=["jax", "torch-grad"])
def test_a_0d_array_is_a_probability(wrap):
    """``alpha=jnp.float32(0.05)`` (what jnp arithmetic such as ``0.05 / jnp.array(k)``
    gives) was refused as "alpha=Array(0.05, dtype=float32): must be a number strictly
    between 0 and 1", a value that is (a review of the 0-d sentence); it is its number,
    the verdict that of the Python float, and one outside (0, 1) is still refused."""
    x = np.random.default_rng(3).normal(1.0, 1.0, 1000)
    for alpha in (np.float32(0.05), np.float64(0.05)):
        r = mv.check_unbiased(x, 1.0, alpha=wrap(alpha))
        assert r.alpha == float(alpha) and r.p_value == mv.check_unbiased(x, 1.0).p_value
    assert mv.check_sampler(_sample, _pdf, "square", n_samples=4000,
                            alpha=wrap(0.05)).alpha == 0.05
    assert mv.compare_images(_IMG, _IMG, test_var=_IMG, ref_var=_IMG, test_n=4, ref_n=4,
                             alpha=wrap(0.05)).passed
    with pytest.raises(mv.InvalidArgument, match=r"alpha=.*: must be a number strictly"):
        mv.check_unbiased(x, 1.0, alpha=wrap(1.5))


class _BFloat16Tensor:
    """A torch bfloat16 tensor as numpy meets it: ``np.asarray`` raises torch's
    TypeError (torch 2.13: "Got unsupported ScalarType BFloat16")."""

    dtype = "torch.bfloat16"

    def __init__(self, a):
        self._a = np.asarray(a)

    def __array__(self, dtype=None, copy=None):
        raise TypeError("Got unsupported ScalarType BFloat16")

    def detach(self):
        return self

    def cpu(self):
        return self

    def __len__(self):
        return len(self._a)


@pytest.mark.parametrize("call", [
    lambda: mv.check_sampler(lambda u: _BFloat16Tensor(_sample(u)), _pdf, "square",
                             n_samples=4000),
    lambda: mv.check_sampler(_sample, lambda x: _BFloat16Tensor(_pdf(x)), "square",
                             n_samples=4000),
    lambda: mv.check_unbiased(_BFloat16Tensor(_EST), 2.0),
    lambda: mv.check_unbiased(_EST, _BFloat16Tensor(2.0)),
    lambda: mv.compare_images(_BFloat16Tensor(_IMG), _IMG, test_var=_IMG, ref_var=_IMG,
                              test_n=16, ref_n=16),
], ids=["points", "pdf", "estimates", "expected", "image"])
def test_bfloat16_is_refused_saying_to_judge_a_float32_version(call):
    """bfloat16 (a differentiable renderer's) was refused as "not an array of numbers
    (Got unsupported ScalarType BFloat16)" (JAX's as "dtype bfloat16: expected real
    numbers") with nothing saying what to do (an outside review); it is refused naming
    bfloat16 and the conversion to float32."""
    with pytest.raises(mv.InvalidArgument, match=r"bfloat16 values .*judge a float32 "
                                                 r"version: t\.float\(\)"):
        call()


class _TorchLike:
    """A torch tensor as numpy meets it: its ``dtype`` is torch's (``torch.float32``),
    none of numpy's, and ``np.asarray`` reads its values."""

    dtype = "torch.float32"

    def __init__(self, a):
        self._a = np.asarray(a)

    def __array__(self, dtype=None, copy=None):
        return self._a if dtype is None else self._a.astype(dtype)


@pytest.mark.parametrize("store", [np.float32, np.float16])
def test_images_given_as_torch_tensors_are_read_by_their_values_type(store):
    """Every image given as a torch tensor raised numpy's bare "Cannot interpret
    'torch.float32' as a data type": the images' rounding read their ``dtype``, which is
    torch's. Their values' type is read, float16's rounding kept (the verdict as for the
    same numpy arrays)."""
    a = _IMG.astype(store)
    got = mv.compare_images(_TorchLike(a), a, test_var=_TorchLike(a), ref_var=a,
                            test_n=16, ref_n=16)
    want = mv.compare_images(a, a, test_var=a, ref_var=a, test_n=16, ref_n=16)
    assert got.passed and got.p_value == want.p_value


def test_a_failing_comparison_of_tensors_that_require_grad_is_judged_and_guessed():
    """The convention guess of a failing comparison read the images by np.asarray and
    raised torch's "Can't call numpy() on Tensor that requires grad", where the
    comparison itself had read them (a read-only review): a correct image 1.3 times the
    reference fails, naming the factor, on either side."""
    ref = np.random.default_rng(3).gamma(2.0, 0.5, (12, 12, 3)) + 0.5
    var = np.full(ref.shape, 0.01)
    r = mv.compare_images(_GradTensor(ref * 1.3), ref, test_var=_GradTensor(var * 1.69),
                          ref_var=var, test_n=16, ref_n=16, perceptual=False)
    assert not r.passed and "1.3 times the reference" in r.messages[-1], r.messages
    r = mv.compare_images(ref * 1.3, _GradTensor(ref), test_var=var * 1.69,
                          ref_var=_GradTensor(var), test_n=16, ref_n=16, perceptual=False)
    assert not r.passed and r.details["convention"] is not None, r.messages
