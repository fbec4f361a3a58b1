"""Bad input fails early with mcverify.InvalidArgument naming the parameter."""

import subprocess
import sys

import numpy as np
import pytest

import mcverify as mv

S = lambda u: u  # noqa: E731
P = lambda x: np.ones(len(x))  # noqa: E731

CASES = [
    ("sample-not-callable", lambda: mv.check_sampler(3, P, "square"), "sample="),
    ("pdf-not-callable", lambda: mv.check_sampler(S, "pdf", "square"), "pdf="),
    ("unknown-domain", lambda: mv.check_sampler(S, P, "torus"), "domain="),
    ("n-zero", lambda: mv.check_sampler(S, P, "square", n_samples=0), "n_samples=0"),
    ("n-float", lambda: mv.check_sampler(S, P, "square", n_samples=1e6), "n_samples="),
    ("alpha-one", lambda: mv.check_sampler(S, P, "square", alpha=1.0), "alpha="),
    ("resolution-zero", lambda: mv.check_sampler(S, P, "square", resolution=(3, 0)),
     "resolution="),
    ("resolution-wrong-len", lambda: mv.check_sampler(S, P, "square", resolution=(3,)),
     "resolution="),
    ("negative-seed", lambda: mv.check_sampler(S, P, "square", seed=-1), "seed=-1"),
    ("sample-wrong-shape", lambda: mv.check_sampler(lambda u: u[:, :1], P, "square",
                                                    n_samples=10), "sample returned shape"),
    ("pdf-wrong-shape", lambda: mv.check_sampler(S, lambda x: np.ones((len(x), 2)), "square",
                                                 n_samples=100), "pdf returned shape"),
    ("inverse-not-callable", lambda: mv.check_inverse(S, None, 2), "inverse="),
    ("inverse-dim-zero", lambda: mv.check_inverse(S, S, 0), "sample_dim=0"),
    ("unbiased-2d", lambda: mv.check_unbiased(np.ones((3, 3)), 1.0), "samples"),
    ("unbiased-nan-expected", lambda: mv.check_unbiased(np.ones(3), float("nan")),
     "expected=nan"),
    ("variance-negative", lambda: mv.check_variance(np.ones(3), -1.0), "expected_variance"),
    ("convergence-two-ns", lambda: mv.check_convergence(lambda n, s: 0.0, 0.0, ns=(1, 2)),
     "ns="),
    ("same-dist-bad-array", lambda: mv.check_same_distribution("abc", S, "square"),
     "sample_a"),
    # found by a review of inputs not in the repository
    ("resolution-beyond-memory", lambda: mv.check_sampler(S, P, "hemisphere",
                                                          resolution=10 ** 5),
     "resolution=(100000, 100000.: 10,000,000,000 histogram cells"),
    ("interval-text", lambda: mv.Interval("a", 1), "Interval(a='a'.: must be a real number"),
    ("interval-overflowing-width", lambda: mv.Interval(-1e308, 1e308), "b - a finite"),
    # an int beyond float64's range was Python's bare OverflowError (7 December)
    ("interval-int-beyond-float", lambda: mv.Interval(0, 10 ** 400),
     r"Interval.b=\.\.\.\): an integer beyond float64.s range"),
    # a density on it overflows: accepted until 7 December, then every check's pdf was inf
    ("interval-too-narrow-for-a-density", lambda: mv.Interval(0, 1e-321),
     "Interval(a=0.0, b=1e-321.: b - a = .* is so small that a density"),
    ("rejection-string", lambda: mv.check_sampler(S, P, "square", rejection="False"),
     "rejection='False'"),
    ("pilot-string", lambda: mv.check_sampler(S, P, "square", pilot="no"), "pilot='no'"),
    ("same-dist-rejection-none", lambda: mv.check_same_distribution(S, S, "square",
                                                                    rejection=None),
     "rejection=None"),
    ("contamination-not-a-result", lambda: mv.detectable_contamination("x"), "result=str"),
    ("inverse-returns-text", lambda: mv.check_inverse(S, lambda x: np.full(x.shape, "a"), 2,
                                                      n_samples=100),
     "inverse returned dtype"),
    ("same-dist-array-of-none", lambda: mv.check_same_distribution(
        np.full((100, 2), None), S, "square", n_samples=100), "sample_a: must be"),
    # half points saved from a GPU buffer: read as float64, a correct unit-vector sampler
    # failed with 95 % of them "outside the sphere domain" (7 December)
    ("same-dist-float16-array", lambda: mv.check_same_distribution(
        S, np.full((100, 2), 0.5, dtype=np.float16), "square", n_samples=100),
     "sample_b: an array of float16 points: judge float32 or float64 ones"),
    ("n-beyond-2^53", lambda: mv.check_sampler(S, P, "square", n_samples=10 ** 30),
     "n_samples=1000000000000000000000000000000: at most 2\\*\\*53"),
    # a name that is no string reached the JUnit writer, which raised a bare TypeError
    ("sampler-name-int", lambda: mv.check_sampler(S, P, "square", name=3, n_samples=100),
     "name=3: must be a string"),
    ("inverse-name-int", lambda: mv.check_inverse(S, S, 2, name=3), "name=3: must be"),
    ("same-dist-name-int", lambda: mv.check_same_distribution(S, S, "square", name=3,
                                                              n_samples=100),
     "name=3: must be"),
    ("unbiased-name-int", lambda: mv.check_unbiased(np.arange(5.0), 2.0, name=3),
     "name=3: must be"),
    ("unbiased-draw-name-list", lambda: mv.check_unbiased(lambda b: np.arange(5.0), 2.0,
                                                          batches=2, name=["a"]),
     "name=\\['a'\\]: must be"),
    ("variance-name-int", lambda: mv.check_variance(np.arange(5.0), name=3),
     "name=3: must be"),
    ("convergence-name-int", lambda: mv.check_convergence(lambda n, s: 0.0, 0.0, name=3),
     "name=3: must be"),
    ("images-name-int", lambda: mv.compare_images(
        np.ones((4, 4)), np.ones((4, 4)), test_var=np.ones((4, 4)),
        ref_var=np.ones((4, 4)), test_n=4, ref_n=4, name=3), "name=3: must be"),
    # a ragged sequence raised numpy's bare "setting an array element with a sequence"
    ("unbiased-ragged", lambda: mv.check_unbiased([[1.0, 2.0], [3.0]], 2.0),
     "samples: not an array of numbers"),
    ("variance-ragged", lambda: mv.check_variance([[1.0, 2.0], [3.0]]),
     "samples: not an array of numbers"),
    ("unbiased-draw-ragged", lambda: mv.check_unbiased(lambda b: [[1.0, 2.0], [3.0]], 2.0,
                                                       batches=2),
     "samples.0.: not an array of numbers"),
    ("images-ragged-var", lambda: mv.compare_images(
        np.ones((4, 4)), np.ones((4, 4)), test_var=[[1.0, 2.0], [3.0]],
        ref_var=np.ones((4, 4)), test_n=4, ref_n=4), "test_var: not an array of numbers"),
    ("sample-returns-ragged", lambda: mv.check_sampler(lambda u: [[0.1, 0.2], [0.3]], P,
                                                       "square", n_samples=2),
     "sample returned .*: not an array of numbers"),
    ("pdf-returns-ragged", lambda: mv.check_sampler(S, lambda x: [[1.0], [1.0, 2.0]],
                                                    "square", n_samples=2),
     "pdf returned .*: not an array of numbers"),
    ("inverse-sample-returns-ragged", lambda: mv.check_inverse(
        lambda u: [[0.1, 0.2], [0.3]], S, 2, n_samples=2), "sample returned .*: not an array"),
    # a masked array's values under its mask were read as data (np.asarray drops the
    # mask): a pdf of np.ma.sqrt(-x) counted the negative x as densities
    ("pdf-returns-masked", lambda: mv.check_sampler(
        S, lambda x: np.ma.masked_less(np.ones(len(x)), 0.0) + np.ma.masked_array(
            np.zeros(len(x)), mask=np.arange(len(x)) == 0), "square", n_samples=2),
     "pdf returned .*: a masked array with 1 masked values"),
    ("unbiased-masked", lambda: mv.check_unbiased(
        np.ma.masked_invalid([1.0, np.nan, 3.0, 2.0]), 2.0),
     "samples: a masked array with 1 masked values"),
    ("images-masked-mean", lambda: mv.compare_images(
        np.ma.masked_greater(np.eye(4), 0.5), np.ones((4, 4)), test_var=np.ones((4, 4)),
        ref_var=np.ones((4, 4)), test_n=4, ref_n=4), "test_mean: a masked array with 4"),
    # a flag given as text was read as true (perceptual="no" measured ΔE and FLIP)
    ("images-perceptual-string", lambda: mv.compare_images(
        np.ones((4, 4)), np.ones((4, 4)), test_var=np.ones((4, 4)),
        ref_var=np.ones((4, 4)), test_n=4, ref_n=4, perceptual="no"),
     "perceptual='no': must be True or False"),
    # mutants of _validate that every test let live (a mutation review): each of these
    # was accepted once its check was dropped
    ("unbiased-bool-expected", lambda: mv.check_unbiased(np.ones(3), True),
     "expected=True: must be a real number"),
    ("variance-bool-expected", lambda: mv.check_variance(np.ones(3), False),
     "expected_variance=False: must be a real number"),
    ("resolution-bool-entry", lambda: mv.check_sampler(S, P, "square", resolution=(True, 3)),
     "resolution=(True, 3.: every entry must be an integer >= 1"),
    # a numpy array of one pdf value is refused (a Dr.Jit one of width 1 is its number)
    ("pdf-returns-numpy-one-value", lambda: mv.check_sampler(S, lambda x: np.ones(1),
                                                             "square", n_samples=100),
     "pdf returned shape .1,.: expected"),
    ("seed-bool", lambda: mv.check_sampler(S, P, "square", seed=True, n_samples=100),
     "seed=True: must be an integer"),
    ("inverse-dim-bool", lambda: mv.check_inverse(S, S, True, n_samples=100),
     "sample_dim=True: must be an integer"),
]


@pytest.mark.parametrize("call,match", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_invalid_calls_raise_invalid_argument(call, match):
    with pytest.raises(mv.InvalidArgument, match=match.replace("(", r"\(")):
        call()


def test_invalid_argument_is_a_value_error():
    assert issubclass(mv.InvalidArgument, ValueError)


@pytest.mark.parametrize("power", [1.5, 0.0, float("nan")])
def test_detectable_contamination_names_a_bad_power(power):
    r = mv.check_sampler(lambda u: np.sqrt(u), lambda x: 2 * x[:, 0], "interval",
                         n_samples=20_000, seed=0)
    with pytest.raises(mv.InvalidArgument, match="power="):
        mv.detectable_contamination(r, power=power)


def test_a_checks_name_is_a_string_or_its_default():
    assert mv.check_unbiased(np.arange(5.0), 2.0, name=None).name == "unbiased"
    assert mv.check_variance(np.ones(5), name="").name == "variance"
    assert mv.check_sampler(S, P, "square", n_samples=100, name=None).name == "sampler:<lambda>"
    assert mv.check_inverse(S, S, 2, n_samples=10, name=np.str_("mine")).name == "mine"


class _NoRepr(np.ndarray):
    """An array whose repr fails the test: a message is formatted only for an error."""

    def __repr__(self):
        raise AssertionError("repr of a valid result taken")


def test_a_valid_callable_result_is_not_formatted_for_a_message():
    # every chunk's points and pdf values had been repr'd (a millisecond for 1e6 points)
    # for a message that is only shown when the value is bad
    square = lambda u: np.asarray(u).view(_NoRepr)  # noqa: E731
    ones = lambda x: np.ones(len(x)).view(_NoRepr)  # noqa: E731
    assert mv.check_sampler(square, ones, "square", n_samples=1000).passed
    assert mv.check_inverse(square, lambda x: np.asarray(x), 2, n_samples=100).passed
    assert mv.check_pdf_consistency(lambda u: (square(u), ones(u)), ones, sample_dim=2,
                                    n_samples=100).passed


@pytest.mark.parametrize("call", [
    lambda: mv.check_unbiased(np.ones(10), 10**400),
    lambda: mv.check_inverse(lambda u: u, lambda x: x, 1, atol=10**400),
    lambda: mv.check_convergence(lambda n, s: 0.5, -(10**400)),
], ids=["unbiased-expected", "inverse-atol", "convergence-expected"])
def test_a_real_argument_beyond_float64_is_named(call):
    """An integer beyond float64's range given for a real argument raised numpy's
    TypeError ("ufunc 'isfinite' not supported") or OverflowError, naming nothing."""
    with pytest.raises(mv.InvalidArgument, match="beyond float64's range"):
        call()


_UNDER_ULIMIT = r"""
import resource, sys
import numpy as np
import mcverify as mv
with open("/proc/self/status") as f:
    size = next(int(l.split()[1]) * 1024 for l in f if l.startswith("VmSize:"))
# 1.5 GiB of address space beyond what this process maps now, as `ulimit -v` gives
resource.setrlimit(resource.RLIMIT_AS, (size + 3 * 2 ** 29, resource.RLIM_INFINITY))
try:
    mv.check_sampler(lambda u: u, lambda x: np.ones(len(x)), mv.Square(),
                     n_samples=10_000, resolution=(3000, 3000), seed=1)
except mv.InvalidArgument as e:
    print("refused:", e)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc/self/status")
def test_the_memory_guard_counts_an_address_space_limit():
    """Under `ulimit -v` the guard read MemAvailable alone: 3000 x 3000 cells (4.3 GiB)
    passed it with 1.5 GiB left to map, and numpy raised a raw MemoryError half-way (an
    outside review). Now refused before any work, naming the resolution."""
    p = subprocess.run([sys.executable, "-c", _UNDER_ULIMIT], capture_output=True,
                       text=True, timeout=300)
    assert p.returncode == 0 and "refused: resolution=(3000, 3000)" in p.stdout, \
        p.stdout + p.stderr[-2000:]
    assert "GiB of memory, more than half of the" in p.stdout


def test_a_cgroups_page_cache_counts_as_memory_left(tmp_path):
    """memory.current counts the page cache the cgroup holds, which the kernel gives back
    under pressure: a CI container that had read many files looked full to the guards."""
    from mcverify import _validate

    (tmp_path / "cgroup").write_text("0::/ci\n")
    folder = tmp_path / "fs" / "ci"
    folder.mkdir(parents=True)
    (folder / "memory.max").write_text("1000\n")
    (folder / "memory.current").write_text("900\n")
    (folder / "memory.stat").write_text("anon 300\nfile 600\nactive_file 100\n"
                                        "inactive_file 500\n")
    left = _validate._cgroup_left(str(tmp_path / "cgroup"), str(tmp_path / "fs"))
    assert left == 1000 - 900 + 500
    (folder / "memory.max").write_text("max\n")
    assert _validate._cgroup_left(str(tmp_path / "cgroup"), str(tmp_path / "fs")) is None


def test_the_memory_guards_read_the_least_that_is_left(monkeypatch):
    """MemAvailable, what `ulimit -v` leaves and what the cgroup's (a container's) limit
    leaves each bound the memory available: the guards read the least of them. Reading
    MemAvailable alone where a cgroup's limit is lower passed every test (a mutation
    review); a CI container's memory.max is that limit."""
    from mcverify import _validate

    monkeypatch.setattr(_validate, "_address_space_left", lambda: None)
    monkeypatch.setattr(_validate, "_cgroup_left", lambda: 2 ** 20)
    assert _validate._available_memory() == 2 ** 20
    with pytest.raises(mv.InvalidArgument, match=r"resolution=\(300, 300\): 90,000 "
                       r"histogram cells need about .* more than half of the 1 MiB"):
        mv.check_sampler(S, P, "square", n_samples=100, resolution=300)
    monkeypatch.setattr(_validate, "_address_space_left", lambda: 2 ** 19)
    assert _validate._available_memory() == 2 ** 19


def test_an_intervals_cells_are_counted_with_their_ks_split(monkeypatch):
    """An interval's histogram keeps 64 cells a bin for its KS statistic, and the memory
    guard counts them: counting the bins alone (64 times too few) failed no test (a
    mutation review). 20,000 bins need 20,000 x 64 x 512 bytes, 625 MiB, more than half
    of 1 GiB; 10 MiB without the split."""
    from mcverify import _validate

    monkeypatch.setattr(_validate, "_available_memory", lambda: 2 ** 30)    # 1 GiB
    with pytest.raises(mv.InvalidArgument, match=r"resolution=\(20000,\): 1,280,000 "
                                                 r"histogram cells need about 625 MiB"):
        mv.check_sampler(S, P, "interval", n_samples=100, resolution=20_000)


def test_a_numpy_bool_is_a_flag():
    """A flag computed with numpy (``rejection=np.any(mask)``, a config read into an
    array) is numpy's bool, accepted as Python's is: refusing it failed no test (a
    mutation review). Seeded, α = 0.01: the identity on the square with its pdf passes."""
    r = mv.check_sampler(S, P, "square", n_samples=1000, rejection=np.False_,
                         pilot=np.bool_(True))
    assert r.passed, r.failures


_LEFT_UNDER_ULIMIT = r"""
import resource
from mcverify import _validate
with open("/proc/self/status") as f:
    size = next(int(l.split()[1]) * 1024 for l in f if l.startswith("VmSize:"))
resource.setrlimit(resource.RLIMIT_AS, (size + 2 ** 30, resource.RLIM_INFINITY))
print(size, _validate._address_space_left(), _validate._available_memory())
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc/self/status")
def test_what_ulimit_leaves_is_the_limit_less_what_is_mapped():
    """Under `ulimit -v` what is left to map is the limit less the process's VmSize, not
    the limit: a Python process with numpy and numba has mapped a GiB or more before any
    check, and a guard reading the limit alone passed every test (a mutation review)."""
    p = subprocess.run([sys.executable, "-c", _LEFT_UNDER_ULIMIT], capture_output=True,
                       text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-2000:]
    size, left, avail = map(int, p.stdout.split())
    # 1 GiB beyond what it mapped, less the little it has mapped since
    assert 2 ** 29 < left <= 2 ** 30 and avail <= left, (size, left, avail)


def _v1_memory_group(folder, limit, used, inactive):
    folder.mkdir(parents=True)
    (folder / "memory.limit_in_bytes").write_text(f"{limit}\n")
    (folder / "memory.usage_in_bytes").write_text(f"{used}\n")
    (folder / "memory.stat").write_text(f"inactive_file 7\ntotal_inactive_file {inactive}\n")


def test_a_cgroup_v1_memory_limit_counts_as_memory_left(tmp_path):
    """A container on a host of cgroup v1, or of both (v2's hierarchy without its memory
    controller, as on Ubuntu 20.04 and on the machine this was found on): only v2's
    memory.max was read, so a v1 container's limit was none, and a resolution it could
    not hold passed the guard (a mutation review)."""
    from mcverify import _validate

    proc = tmp_path / "cgroup"
    proc.write_text("9:name=systemd:/\n4:cpu,memory:/ci/job\n0::/\n")
    fs = tmp_path / "fs"
    _v1_memory_group(fs / "memory" / "ci" / "job", 1000, 900, 500)
    assert _validate._cgroup_left(str(proc), str(fs)) == 1000 - 900 + 500
    # a container sees its own group at the root, named by the host's path
    fs = tmp_path / "container"
    _v1_memory_group(fs / "memory", 3000, 1000, 0)
    assert _validate._cgroup_left(str(proc), str(fs)) == 2000
    # unlimited: v1 writes 2**63 less a page
    fs = tmp_path / "unlimited"
    _v1_memory_group(fs / "memory", 9223372036854771712, 1000, 0)
    assert _validate._cgroup_left(str(proc), str(fs)) is None


def test_a_pdf_of_one_column_is_its_values():
    """A pdf returning shape (n, 1), a column (``x[:, :1] * 0 + 1``, a matrix product's
    result), is read as its n values: reading it so was dropped and no test failed (a
    mutation review). Seeded, α = 0.01."""
    r = mv.check_sampler(S, lambda x: np.ones((len(x), 1)), "square", n_samples=1000)
    assert r.passed, r.failures
