"""Argument validators shared by the public functions: each raises ``InvalidArgument``
naming the parameter, the value received and what is valid, before any work is done."""

from __future__ import annotations

import inspect
import numbers
import os
import re

import numpy as np

from .errors import InvalidArgument


def _show(v) -> str:
    r = repr(v)
    return r if len(r) <= 60 else r[:57] + "..."


def callable_(name: str, v) -> None:
    if not callable(v):
        raise InvalidArgument(f"{name}={_show(v)}: must be callable "
                              f"(got {type(v).__name__})")


def draw(name: str, sample, u: np.ndarray):
    """``sample(u)``, its exceptions as raised (the user's own traceback), an IndexError
    with a note of the uniforms' shape: a sampler reading ``u[:, 2]`` of the domain's
    default two columns raised numpy's bare "index 2 is out of bounds for axis 1 with
    size 2", nothing saying that ``sample_dim`` sets them (an outside review)."""
    try:
        return sample(u)
    except IndexError as e:
        if hasattr(e, "add_note"):      # Python 3.11
            e.add_note(f"mcverify called {name} with uniform numbers u of shape {u.shape}: "
                       f"{u.shape[1]} a draw; pass sample_dim=K where it takes K")
        raise
    except Exception as e:
        compiled_note(e, name, sample, u, "uniform numbers u", "draw")
        tensor_note(e, name, u, "uniform numbers u")
        arguments_note(e, name, sample, u, "uniform numbers u", "draw")
        raise


def call(name: str, f, x, what: str = "points x"):
    """``f(x)`` for a pdf, an inverse or an ``f`` of points (n, d), with
    ``compiled_note`` on what numba refuses."""
    try:
        return f(x)
    except Exception as e:
        compiled_note(e, name, f, x, what, "point")
        tensor_note(e, name, x, what)
        arguments_note(e, name, f, x, what, "point")
        raise


def tensor_note(e: BaseException, name: str, arg, what: str) -> None:
    """A note on a callable written for torch tensors (``u.sqrt()``, ``torch.sqrt(u)``,
    ``u.clamp(0, 1)``) given the numpy array every check passes: torch's or Python's
    "'numpy.ndarray' object has no attribute 'clamp'" or "sqrt(): argument 'input'
    (position 1) must be Tensor, not numpy.ndarray" escaped from the user's code with
    nothing saying what mcverify had passed or how to wrap it (an outside review). An
    AttributeError or TypeError naming numpy.ndarray, as both libraries word it."""
    if not hasattr(e, "add_note") or not isinstance(e, (AttributeError, TypeError)) \
            or "numpy.ndarray" not in str(e) or not isinstance(arg, np.ndarray):
        return
    e.add_note(f"mcverify called {name} with {what} as a numpy array ({arg.dtype}, "
               f"shape {arg.shape}); a function of torch tensors takes it wrapped: pass "
               f"lambda a: {name}(torch.from_numpy(a)) (what it returns is read through "
               "np.asarray, a tensor as t.detach().cpu())")


def arguments_note(e: BaseException, name: str, f, arg, what: str, row: str) -> None:
    """A note on a Python callable that cannot be called with one argument: a port of
    pbrt's ``SampleUniformDiskPolar(Point2f u)`` written ``sample(u0, u1)``, or a pdf
    ``pdf(x, y)``, raised Python's bare "missing 1 required positional argument: 'u1'"
    from inside the check, nothing saying what mcverify passes (an outside review).
    Only where the call itself failed (not a TypeError from inside the function, behind
    a decorator that takes the batch) and the callable's own signature refuses a single
    argument; ``lambda a: f(*a.T)`` is advised only where ``f`` takes one argument a
    coordinate, else its signature is shown (a method unbound, an extra argument to
    bind, a keyword-only one: the advice was false there; a read-only review)."""
    if not hasattr(e, "add_note") or not isinstance(e, TypeError) or _compiled(f):
        return
    tb = e.__traceback__
    if tb is None or tb.tb_next is not None:     # raised inside f, not by calling it
        return
    try:
        signature = inspect.signature(f)
        signature.bind(arg)
    except TypeError:
        pass
    except ValueError:      # no signature to read (a builtin)
        return
    else:
        return
    a = np.asarray(arg)
    params = signature.parameters.values()
    positional = [p for p in params if p.default is p.empty and p.kind in
                  (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)]
    keyword = [p for p in params if p.default is p.empty and p.kind == p.KEYWORD_ONLY]
    columns = a.shape[-1] if a.ndim == 2 else 1
    advice = (f"pass lambda a: {name}(*a.T) where it takes one array a coordinate"
              if len(positional) == columns and not keyword else
              f"its signature is {name}{signature}: give a function of that one array, "
              "with any other argument bound (a method of an instance, lambda a: "
              f"{name}(a, ...))")
    e.add_note(f"mcverify called {name} with one {a.dtype} array of {what}, shape "
               f"{a.shape}, a row per {row}; it takes other arguments: {advice}")


def _compiled(f) -> bool:
    """A numba function: a jitted dispatcher (``@njit``) or a ``@vectorize`` or
    ``@guvectorize`` ufunc (numba's or a plain ``np.ufunc``); numba is not imported."""
    return isinstance(f, np.ufunc) or type(f).__module__.split(".")[0] == "numba"


def compiled_note(e: BaseException, name: str, f, arg, what: str, row: str) -> None:
    """A note on numba's refusal of the batch mcverify hands a compiled callable: an
    ``@njit`` function of one draw's numbers raised "not enough arguments: expected 2,
    got 1", a float32-only signature "No matching definition for argument type(s)
    array(float64, 2d, C)", a function of one row a TypingError pages long, nothing of
    what mcverify had passed or what to change (an outside review)."""
    numba_error = type(e).__module__.split(".")[0] == "numba"
    if not hasattr(e, "add_note") or not _compiled(f) or not (
            numba_error or isinstance(e, TypeError)):
        return
    a = np.asarray(arg)
    e.add_note(f"mcverify called {name} with one {a.dtype} array of {what}, shape "
               f"{a.shape}, a row per {row}: a numba function must take that batch; one "
               f"of a single {row}'s numbers, or compiled for other types (a float32-only "
               "signature), cannot: loop over the rows in an @njit function, or convert "
               "in a Python wrapper (lambda a: f(a.astype(np.float32)))")


def integer(name: str, v, *, minimum: int | None = None, maximum: int | None = None) -> int:
    if isinstance(v, bool) or not isinstance(v, numbers.Integral):
        raise InvalidArgument(f"{name}={_show(v)}: must be an integer")
    if minimum is not None and v < minimum:
        raise InvalidArgument(f"{name}={v}: must be >= {minimum}")
    if maximum is not None and v > maximum:
        raise InvalidArgument(f"{name}={v}: must be <= {maximum}")
    return int(v)


def boolean(name: str, v) -> bool:
    """A flag must be a bool (numpy's included): ``rejection="False"`` would be true."""
    if not isinstance(v, (bool, np.bool_)):
        raise InvalidArgument(f"{name}={_show(v)}: must be True or False")
    return bool(v)


def label(v, default: str) -> str:
    """A check's ``name`` (its name in reports and JUnit): a string, ``default`` for None
    or "" (a number reached the JUnit writer, which raised a bare TypeError)."""
    if v is None or (isinstance(v, str) and not v):
        return default
    if not isinstance(v, str):
        raise InvalidArgument(f"name={_show(v)}: must be a string (the check's name in "
                              f"reports), got {type(v).__name__}")
    return v


def probability(name: str, v) -> float:
    # a 0-d array is its number here too: alpha=jnp.float32(0.05) was refused as "must
    # be a number strictly between 0 and 1" (a review of the README's 0-d sentence)
    x = scalar(v)
    if isinstance(x, bool) or not isinstance(x, numbers.Real) or not (0.0 < x < 1.0):
        raise InvalidArgument(f"{name}={_show(v)}: must be a number strictly between 0 and 1")
    return float(x)


def scalar(v):
    """``v``, or the number a 0-d array of real numbers holds, as a numpy scalar of its
    type: JAX's ``jnp.float32(0.5)`` and any jnp arithmetic on scalars give a 0-d
    ``Array``, torch's a 0-d tensor, which every real argument refused as "must be a
    real number" (an outside review: the float32 ``expected`` the README names,
    ``np.float32(np.pi)``, written in JAX). Arrays of one element, (1,), stay arrays."""
    if isinstance(v, (numbers.Real, str, bytes)) or v is None:
        return v
    try:
        a = np.asarray(host(v))
    except Exception:       # noqa: BLE001 - not an array: refused as it is
        return v
    return a[()] if a.shape == () and real_dtype(a.dtype) else v


def real(name: str, v, *, finite: bool = True, minimum: float | None = None) -> float:
    v = scalar(v)
    if isinstance(v, bool) or not isinstance(v, numbers.Real):
        # a 0-d bfloat16 (torch's torch.bfloat16, JAX's bfloat16) gets what to do with it
        # (a read-only review: "must be a real number" and no more)
        bf16 = "bfloat16" in str(getattr(v, "dtype", "")).lower()
        raise InvalidArgument(f"{name}={_show(v)}: must be a real number"
                              + (f"; {_BFLOAT16}" if bf16 else ""))
    try:
        # an integer or fraction beyond float64's range (10**400) raised OverflowError
        # or numpy's TypeError from isfinite, naming nothing (the final review)
        x = float(v)
    except OverflowError:
        raise InvalidArgument(f"{name}={_show(v)}: beyond float64's range") from None
    if finite and not np.isfinite(x):
        raise InvalidArgument(f"{name}={v}: must be finite")
    if minimum is not None and not x >= minimum:
        raise InvalidArgument(f"{name}={v}: must be >= {minimum}")
    return x


def _available_memory() -> int | None:
    """Bytes of memory available now (Linux: MemAvailable, else physical memory), at most
    what this process may still map under its address-space limit (``ulimit -v``) and
    what its cgroup (a container's memory limit) has left: MemAvailable counts neither,
    and under ``ulimit -v 3000000`` a 3000 x 3000 resolution passed the guard and raised
    numpy's MemoryError half-way (an outside review)."""
    avail = None
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    avail = int(line.split()[1]) * 1024
                    break
    except (OSError, ValueError, IndexError):
        pass
    if avail is None:
        try:
            avail = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
        except (OSError, ValueError, AttributeError):
            pass
    for left in (_address_space_left(), _cgroup_left()):
        if left is not None:
            avail = left if avail is None else min(avail, left)
    return avail


def _address_space_left() -> int | None:
    """Bytes this process may still map under RLIMIT_AS, or None when unlimited."""
    try:
        import resource
        soft = resource.getrlimit(resource.RLIMIT_AS)[0]
        if soft == resource.RLIM_INFINITY:
            return None
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("VmSize:"):
                    return max(soft - int(line.split()[1]) * 1024, 0)
        return soft
    except (ImportError, OSError, ValueError, IndexError):
        return None


def _cgroup_left(proc: str = "/proc/self/cgroup", root: str = "/sys/fs/cgroup") -> int | None:
    """Bytes left under this process's cgroup memory limit (its reclaimable page cache
    counted as left), or None when unlimited: cgroup v2's ``memory.max``, else v1's
    ``memory.limit_in_bytes``, a container's on a host of cgroup v1 or of both (the
    guards read v2's alone until 8 December, and a v1 container's limit never: a
    mutation review)."""
    try:
        with open(proc, encoding="ascii") as f:
            groups = [line.rstrip("\n").split(":", 2) for line in f]
    except OSError:
        return None
    groups = [(controllers.split(","), rel.lstrip("/")) for _, controllers, rel in
              (g for g in groups if len(g) == 3)]
    folders = [(os.path.join(root, rel), _V2) for c, rel in groups if c == [""]]
    for c, rel in groups:
        if "memory" in c:
            # a container sees its own group at the hierarchy's root, named by the host's path
            folder = os.path.join(root, "memory", rel)
            folders.append((folder if os.path.isdir(folder) else
                            os.path.join(root, "memory"), _V1))
    for folder, files in folders:
        try:
            return _memory_left(folder, *files)
        except (OSError, ValueError, IndexError):
            continue        # not this hierarchy's controller (v2's on a hybrid host)
    return None


#: The files of a cgroup's memory limit, its use and the memory.stat line of its
#: inactive page cache: v2's, and v1's (whose limit is a huge number where unlimited).
_V2 = ("memory.max", "memory.current", "inactive_file ")
_V1 = ("memory.limit_in_bytes", "memory.usage_in_bytes", "total_inactive_file ")


def _memory_left(folder: str, limit_file: str, used_file: str, cache_key: str) -> int | None:
    """The limit in ``folder`` less what is used, plus the inactive page cache (counted in
    the use but given back under pressure: a CI container that had read many files
    looked full); None where unlimited. Raises OSError where the files are not there."""
    with open(os.path.join(folder, limit_file), encoding="ascii") as f:
        limit = f.read().strip()
    if limit == "max" or int(limit) >= 2 ** 62:     # v1's unlimited: 2**63 less a page
        return None
    with open(os.path.join(folder, used_file), encoding="ascii") as f:
        used = int(f.read())
    with open(os.path.join(folder, "memory.stat"), encoding="ascii") as f:
        cache = next((int(line.split()[1]) for line in f if line.startswith(cache_key)), 0)
    return max(int(limit) - used + cache, 0)


def _bytes(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if n < 1024 or unit == "PiB":
            return f"{n:.3g} {unit}"
        n /= 1024


def fits(need: int, needs: str, detail: str = "", hint=None) -> None:
    """Refuse, before any work, ``need`` bytes that are more than half the memory
    available (numpy would raise MemoryError half-way, or the system would swap):
    ``InvalidArgument("{needs} about N of memory{detail}, more than half of the M
    available; {hint}")``, ``needs`` naming what is asked ("passes=20: needs"), ``hint``
    what to do, a string or a function of the bytes available. Every memory guard's one
    comparison and message."""
    avail = _available_memory()
    if avail is None or need <= avail // 2:
        return
    hint = hint(avail) if callable(hint) else hint
    raise InvalidArgument(f"{needs} about {_bytes(need)} of memory{detail}, more than half "
                          f"of the {_bytes(avail)} available" + (f"; {hint}" if hint else ""))


def memory(name: str, n: int, bytes_each: int, what: str, *, width=None,
           least: int = 1) -> None:
    """Refuse ``n`` items of ``bytes_each`` bytes when they need more than half the memory
    available (``fits``). ``width``: ``(parameter, value)`` that sets ``bytes_each``,
    blamed instead of ``name`` when not even ``least`` items fit."""
    if width is not None:
        fits(least * bytes_each, f"{width[0]}={width[1]}: {least} rows of it need",
             f" ({what})")

    def hint(avail):
        most = avail // 2 // bytes_each
        # below ``least`` (a reference's 2 passes) "use at most 1" was no way out
        return f"use at most {most}" if most >= max(least, 1) else \
            f"not even {max(least, 1)} fit (the least {name} allowed): free memory"

    fits(n * bytes_each, f"{name}={n}: needs", f" ({what})", hint)


def negatives(v: np.ndarray) -> tuple[int, tuple, float] | None:
    """(how many entries of ``v`` are negative, the first one's index, its value), or
    None if none is."""
    bad = v < 0
    if not np.any(bad):
        return None
    first = tuple(int(i) for i in np.argwhere(bad)[0])
    return int(np.count_nonzero(bad)), first, float(v[first])


def few_bins_note(name: str, n: int, n_bins: int, limit: str | None = None) -> str | None:
    """A message when a χ² test pooled its histogram into so few bins (fewer than 5
    expected per cell elsewhere) that it can detect only gross errors. ``limit``: why
    there are so few cells whatever ``n`` (an interval holding few values of the points'
    type), where more samples would not help; until 7 December the note said to draw
    more there too (an outside review)."""
    if n_bins >= 5:
        return None
    return (f"{name}={n}: the χ² test pooled its histogram into {n_bins} bin(s), so it has "
            "almost no power (a wrong sampler may pass); "
            + (f"more samples would not help: {limit}" if limit else "draw more samples"))


def seed(name: str, v) -> int:
    return integer(name, v, minimum=0)


def resolution(name: str, v, param_dim: int, *, cell_factor: int = 1,
               bytes_per_cell: int = 0) -> tuple[int, ...] | None:
    """Cells per axis as a tuple; with ``bytes_per_cell``, refused when the
    ``prod(cells) · cell_factor`` cells would need more than half the memory available
    (before any work: numpy raised MemoryError after seconds, or the system was killed)."""
    if v is None:
        return None
    if isinstance(v, numbers.Integral) and not isinstance(v, bool):
        v = (int(v),) * param_dim
    try:
        t = tuple(v)
    except TypeError:
        raise InvalidArgument(f"{name}={_show(v)}: must be an int or a tuple of "
                              f"{param_dim} ints") from None
    if len(t) != param_dim:
        raise InvalidArgument(f"{name}={_show(v)}: this domain needs {param_dim} entries")
    if any(isinstance(r, bool) or not isinstance(r, numbers.Integral) or r < 1 for r in t):
        raise InvalidArgument(f"{name}={_show(v)}: every entry must be an integer >= 1")
    t = tuple(int(r) for r in t)
    cells = int(np.prod(t, dtype=object)) * cell_factor
    fits(cells * bytes_per_cell, f"{name}={_show(v)}: {cells:,} histogram cells need",
         hint="use fewer cells")
    return t


def real_dtype(dtype) -> bool:
    """Whether arrays of ``dtype`` hold real numbers: floating or integer (not object,
    string, complex or boolean)."""
    return np.issubdtype(dtype, np.floating) or np.issubdtype(dtype, np.integer)


def host(v):
    """``v``, or a torch tensor's values where numpy can read them, ``v.detach().cpu()``:
    numpy cannot read a tensor that requires grad (a differentiable renderer's sampler,
    pdf or estimate), and every check raised torch's bare RuntimeError "Can't call
    numpy() on Tensor that requires grad" from inside mcverify (an outside review), nor
    one on a GPU. The checks read values only; the caller's tensor and graph are left
    as they are. torch is not imported: a tensor is what has ``detach`` and ``cpu``
    methods (numpy, JAX and Dr.Jit arrays have neither)."""
    if callable(getattr(v, "detach", None)) and callable(getattr(v, "cpu", None)):
        return v.detach().cpu()
    return v


def numpy_dtype(a) -> np.dtype | None:
    """The numpy type of ``a`` (a numpy dtype, or an array of any library), None where it
    has none numpy reads: a torch tensor's ``dtype``, ``torch.float32``, is none of
    numpy's, and every image given as a torch tensor raised numpy's bare "Cannot
    interpret 'torch.float32' as a data type" (until 7 December; found in a review of
    an outside review's tensor fixes); its values' type, as numpy reads them, is. The
    images' and the estimates' rounding read it so."""
    if a is None or isinstance(a, np.dtype):
        return a
    if isinstance(a, np.ndarray):
        return a.dtype
    try:
        return np.asarray(host(a)).dtype
    except (TypeError, ValueError, RuntimeError):   # refused where it is read
        return None


def as_array(what, v) -> np.ndarray:
    """``np.asarray(v)``, or InvalidArgument saying ``what`` is wrong (a string, or a
    function of no arguments that makes it: a repr of a million points costs about a
    millisecond, which a check paid on every chunk before any error): a ragged sequence
    (``[[1, 2], [3]]``) raised numpy's bare ValueError, naming nothing. A masked array
    with masked values is refused: ``np.asarray`` keeps the values under the mask
    (``np.ma.sqrt(-1.0)``'s is -1.0) and the checks would read them as data."""
    v = host(v)
    if np.ma.is_masked(v):
        what = what() if callable(what) else what
        raise InvalidArgument(f"{what}: a masked array with {int(np.ma.count_masked(v))} "
                              "masked values; the checks read every value (fill them, "
                              "e.g. .filled(np.nan), or leave them out)")
    try:
        a = np.asarray(v)
    except (ValueError, TypeError) as e:
        what = what() if callable(what) else what
        if "BFloat16" in str(e):    # torch's "Got unsupported ScalarType BFloat16"
            raise InvalidArgument(f"{what}: {_BFLOAT16}") from None
        raise InvalidArgument(f"{what}: not an array of numbers ({e})") from None
    if a.dtype.name == "bfloat16":  # JAX's (ml_dtypes'), which numpy holds as its own
        what = what() if callable(what) else what
        raise InvalidArgument(f"{what}: {_BFLOAT16}")
    return a


#: bfloat16 values, a differentiable renderer's: refused as "not an array of numbers" or
#: "dtype bfloat16: expected real numbers" with nothing saying what to do (an outside
#: review); 8 significant bits, 0.4 % rounding, fewer than float16's 11 (refused too)
_BFLOAT16 = ("bfloat16 values (8 significant bits: 0.4 % rounding); judge a float32 "
             "version: t.float() of a torch tensor, x.astype(np.float32) of a JAX array")


def not_a_tuple(name: str, x, n: int, dim: int | None = None) -> None:
    """InvalidArgument where a sampler of points returned ``(points, pdf)`` or
    ``(points, pdf, weight)``, the tuple ``check_pdf_consistency``'s sampler returns: a
    BSDF's one ``sample`` handed to ``check_sampler`` failed as numpy's "inhomogeneous
    shape", or in 1-D and in ``check_inverse`` as points of shape (2, n), "transposed?
    return points.T" (an outside review). A sequence of ``n`` rows is points. Arrays of
    ``n`` values each, as many as the domain's ``dim`` (> 1), are the points' coordinates
    as columns, ``(x, y, z)``, and are told to stack them (a read-only review: they were
    told to pass ``sample(u)[0]``, a 1-D array); where ``dim`` is not known (the points'
    dimension is the sampler's own) both readings are given."""
    if not isinstance(x, (tuple, list)) or len(x) not in (2, 3) or len(x) == n:
        return
    try:
        rows = len(x[0])
    except TypeError:
        return
    if rows != n:
        return
    kind = type(x).__name__
    columns = all(np.ndim(c) == 1 and len(c) == n for c in x)
    stack = "return np.stack(..., axis=-1), a row of coordinates per draw"
    if columns and dim is not None and dim > 1:
        # on a domain of points of dim coordinates a 1-D array is no points: never (points,
        # pdf); (θ, φ) on the sphere are parameters, not its 3 coordinates (a read-only
        # review: told to pass sample(u)[0], which failed again)
        also = ("" if len(x) == dim else f"; the {dim} coordinates of the domain's points, "
                "not their parameters")
        raise InvalidArgument(f"{name} returned a {kind} of {len(x)} arrays of {n} values, "
                              f"the points' coordinates as columns? {stack}{also}")
    parts = "(points, pdf)" if len(x) == 2 else "(points, pdf, weight)"
    pick = f"this check takes the points alone; pass lambda u: {name}(u)[0]"
    if columns and dim is None:
        raise InvalidArgument(f"{name} returned a {kind} of {len(x)} arrays of {n} values: "
                              f"if they are {parts}, as check_pdf_consistency's sampler "
                              f"returns them, {pick}; if they are the points' coordinates "
                              f"as columns, {stack}")
    raise InvalidArgument(f"{name} returned a {kind} of {len(x)} arrays, {parts} as "
                          f"check_pdf_consistency's sampler returns them: {pick}")


def drjit(v) -> bool:
    """A Dr.Jit array (``mi.Float``, ``mi.Vector3f``): its classes derive from
    ``drjit.ArrayBase``; drjit is not imported."""
    return any(c.__module__.split(".")[0] == "drjit" for c in type(v).__mro__)


def transposed(raw, verb: str = "return", noun: str = "points") -> str:
    """The hint for points given as (d, n): ``points.T``, but ``np.array(points).T`` for a
    Dr.Jit array (``mi.Vector3f``, which numpy reads as (3, n)), which has no ``.T``: its
    ``.T`` raised "TypeError: 'mitsuba.Vector3f' is not a matrix or tensor type" (an
    outside review). drjit is not imported: its arrays derive from ``drjit.ArrayBase``."""
    if drjit(raw):
        return f"; transposed? {verb} np.array({noun}).T (a Dr.Jit array has no .T)"
    return f"; transposed? {verb} {noun}.T"


#: Where a direction's two angles (θ, φ) lie, in radians and in degrees: θ in [0, π], φ
#: in [-π, π) or [0, 2π) (renderers differ), as the hint spells them.
_ANGLES = (("radians", np.pi, ("π", "-π", "2π"), ""),
           ("degrees", 180.0, ("180", "-180", "360"), " of np.radians(θ, φ)"))


def angles(a, verb: str = "return") -> str:
    """The hint for directions given as (n, 2) where unit vectors (n, 3) are meant, where
    every row could be a (θ, φ) pair and not all lie in [0, 1] (u itself, or a square's
    points): until 7 December such a sampler was told 'expected (n, 3)' and no more (an
    outside review)."""
    if a.ndim != 2 or a.shape[1] != 2 or not a.size or not np.isfinite(a).all() \
            or (a.min() >= 0.0 and a.max() <= 1.0):
        return ""
    theta, phi = a[:, 0], a[:, 1]
    for unit, half, (pi, minus_pi, two_pi), convert in _ANGLES:
        # in degrees, some value beyond 2π (angles below it read as radians if at all)
        if theta.min() >= 0.0 and theta.max() <= half and phi.min() >= -half \
                and phi.max() <= 2.0 * half and (half == np.pi or np.abs(a).max() > 2 * np.pi):
            return (f"; the first column lies in [0, {pi}] and the second in "
                    f"[{minus_pi}, {two_pi}]: (θ, φ) angles in {unit}? {verb} unit vectors "
                    f"(sin θ cos φ, sin θ sin φ, cos θ){convert}")
    return ""


def points(name: str, x, n: int, dim: int) -> np.ndarray:
    """Output of a user callable as an (n, dim) array (float32 kept, anything else as
    float64), or InvalidArgument."""
    not_a_tuple(name, x, n, dim)
    a = as_array(lambda: f"{name} returned {_show(x)}", x)
    if not real_dtype(a.dtype):
        raise InvalidArgument(f"{name} returned dtype {a.dtype}: expected real numbers")
    if a.dtype == np.float16:
        # 11 bits: a unit vector is off the sphere by up to 1e-3 and read as outside the
        # domain (a probe's correct float16 cosine sampler: 95042 points "outside")
        raise InvalidArgument(f"{name} returned float16 points: judge a float32 or float64 "
                              "version (float16's 11-bit significand puts unit vectors up "
                              "to 1e-3 off the sphere, outside the domain)")
    if dim == 1 and a.shape == (n,):
        a = a.reshape(n, 1)
    if a.shape != (n, dim):
        # the rows it was called on: a pilot's 1000 rows beside n_samples=1e6 read as a
        # mismatch of the user's n; a transposed (dim, n) array gets the hint the arrays
        # of check_same_distribution and check_inverse give (an outside review)
        raise InvalidArgument(f"{name} returned shape {a.shape} for {n} rows: expected "
                              f"({n}, {dim})" + (" or (n,)" if dim == 1 else "")
                              + (transposed(x) if dim > 1 and a.shape == (dim, n) else "")
                              + (angles(a) if dim == 3 and a.shape == (n, 2) else ""))
    return a if a.dtype == np.float32 else a.astype(np.float64, copy=False)


def values(name: str, v, n: int) -> np.ndarray:
    """Output of a user callable as (n,) float64. A single number is taken as that value
    at every point (a constant pdf, e.g. ``lambda x: 1 / (4 * np.pi)``)."""
    a = as_array(lambda: f"{name} returned {_show(v)}", v)
    if not real_dtype(a.dtype):
        raise InvalidArgument(f"{name} returned dtype {a.dtype}: expected real numbers "
                              f"(first value {_show(a.flat[0] if a.size else None)})")
    a = a.astype(np.float64, copy=False)
    if a.shape == () or (a.shape == (1,) and drjit(v)):
        # a Dr.Jit array of width 1 is its one number broadcast, as Dr.Jit reads it:
        # Mitsuba's own mi.warp.square_to_uniform_sphere_pdf returns one, and was
        # refused as "shape (1,): expected (n,)" until 7 December (an outside review)
        return np.full(n, float(a.reshape(())))
    if a.shape == (n, 1):
        a = a.reshape(n)
    if a.shape != (n,):
        raise InvalidArgument(f"{name} returned shape {a.shape}: expected ({n},) or one "
                              "number for all points")
    return a


def samples_1d(name: str, v, *, minimum: int = 2) -> np.ndarray:
    raw = as_array(name, v)
    if np.iscomplexobj(raw):    # numpy would drop the imaginary part with a warning
        raise InvalidArgument(f"{name}: complex values; the checks test real estimates "
                              "(test the real and imaginary parts separately)")
    if not (real_dtype(raw.dtype) or raw.dtype == np.bool_):
        # strings ("1", "2") were read as numbers (found by a probe); booleans stay 0/1,
        # a hit-or-miss estimator's values (found by review)
        got = f"dtype {raw.dtype}"
        if raw.dtype == object and raw.ndim == 0:
            # None, a dict, a generator, which numpy wraps whole: "got dtype object" said
            # nothing of what was given (an outside review)
            got = f"{type(v).__name__} {v!r:.60}"
        raise InvalidArgument(f"{name}: must be a 1-D array of numbers, got {got}")
    a = raw.astype(np.float64, copy=False)
    if a.ndim != 1:
        raise InvalidArgument(f"{name}: must be 1-D, got shape {a.shape}")
    if a.size < minimum:
        raise InvalidArgument(f"{name}: needs at least {minimum} values, got {a.size}")
    return a


def decimal_int(text: str) -> int:
    """An integer option's value (argparse ``type=``): ASCII decimal digits with an
    optional sign. Python's ``int`` also reads ``1_0`` and other scripts' digits
    (``１``), which a command line's seed or count should not accept silently."""
    t = str(text).strip()
    if not re.fullmatch(r"[+-]?[0-9]+", t):
        import argparse

        raise argparse.ArgumentTypeError(f"invalid int value: {text!r} (decimal digits)")
    return int(t)
