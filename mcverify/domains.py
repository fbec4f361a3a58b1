"""Integration domains behind one small interface (as Mitsuba's ``ChiSquareTest`` domains).

A domain maps its points to a parameter cube ``[0, 1]^m`` (m = 1 or 2) by a bijection
with *constant* Jacobian, so a histogram cell in parameter space has measure
``jacobian × cell volume`` and a pdf w.r.t. the domain's measure (length, area, solid
angle) becomes the parameter-space density ``pdf(to_point(s)) × jacobian``. New geometry
never touches the statistics: it only says how to map, what is inside, and how many
random numbers its samplers usually consume.
"""

from __future__ import annotations

import numbers

import numpy as np

from . import _domain_kernels as kernels
from .errors import InvalidArgument

__all__ = ["Domain", "Interval", "Square", "Disk", "Sphere", "Hemisphere", "as_domain"]



class Domain:
    """Base class. Subclasses set ``name``, ``dim`` (coordinates of a point),
    ``param_dim`` (m), ``sample_dim`` (uniform numbers a typical sampler takes),
    ``jacobian`` (measure per unit parameter volume) and ``kind``, the domain's
    branch in ``_domain_kernels`` (``to_param``, ``to_point`` and ``inside`` are numba
    passes there)."""

    name = "domain"
    dim = 1
    param_dim = 1
    sample_dim = 1
    jacobian = 1.0
    #: Tolerance of ``inside`` for points produced in float32 (norms off by ~1e-7).
    tolerance = 1e-5
    #: Kernel identity (``_domain_kernels``) and its float parameters.
    kind = -1
    #: Whether parameter axis 1 is the azimuth φ / 2π.
    _azimuth_axis = False

    @property
    def args(self) -> np.ndarray:
        return np.zeros(2)

    @property
    def measure(self) -> float:
        """Total measure of the domain (length, area or solid angle)."""
        return self.jacobian

    def points(self, x) -> np.ndarray:
        """``x`` as a C-contiguous (n, dim) array: float32 stays float32 (the kernels
        read it in float64), anything else becomes float64."""
        a = np.asarray(x)
        a = a if a.dtype in (np.float32, np.float64) else a.astype(np.float64)
        return np.ascontiguousarray(a.reshape(-1, self.dim))

    def classify(self, x, *, rejection: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Parameters (n, m), clamped to [0, 1), and a status per point
        (``_domain_kernels.VALID`` / ``NONFINITE`` / ``OUTSIDE``, and ``REJECTED`` for
        rows of NaN with ``rejection``), in one numba pass."""
        x = self.points(x)
        s = np.empty((x.shape[0], 2))
        status = np.empty(x.shape[0], dtype=np.int8)
        kernels.to_param_kernel(self.kind, self.args, self.tolerance, x, s, status, rejection)
        return s[:, :self.param_dim], status

    def to_param(self, x) -> np.ndarray:
        """(n, dim) points -> (n, m) parameters in [0, 1)."""
        return self.classify(x)[0]

    def inside(self, x) -> np.ndarray:
        """(n, dim) -> (n,) bool: finite and inside (within ``tolerance``)."""
        return self.classify(x)[1] == kernels.VALID

    def to_point(self, s: np.ndarray) -> np.ndarray:
        """(n, m) parameters -> (n, dim) points, in one numba pass
        (``_domain_kernels.to_point_kernel``)."""
        s = np.ascontiguousarray(np.asarray(s, dtype=np.float64).reshape(-1, self.param_dim))
        out = np.empty((s.shape[0], self.dim))
        kernels.to_point_kernel(self.kind, self.args, s, out)
        return out

    def binning_edges(self, edges):
        """Cell edges in the coordinates the histogram kernel bins in: the parameters
        themselves, except that an azimuth axis is binned by a monotone stand-in for
        φ / 2π that needs no arc tangent (``_domain_kernels.pseudo_azimuth_edges``)."""
        edges = [np.asarray(e, dtype=np.float64) for e in edges]
        if self._azimuth_axis and len(edges) == 2:
            edges[1] = kernels.pseudo_azimuth_edges(edges[1])
        return edges

    def rounding_edges(self, edges, dtype):
        """Cell edges (parameters) for points of ``dtype``: these as they are, except
        on an interval (``Interval.rounding_edges``)."""
        return edges

    def default_resolution(self, n_samples: int) -> tuple[int, ...]:
        """Histogram resolution: about 100 expected samples per cell on average (enough
        for the χ² approximation after pooling, fine enough to localise a bug), capped
        at 512 cells per axis in 1-D and 64 × 128 in 2-D."""
        cells = max(n_samples // 100, 8)
        if self.param_dim == 1:
            return (int(min(max(cells, 8), 512)),)
        rows = int(np.clip(np.sqrt(cells / 2.0), 4, 64))
        return (rows, 2 * rows)

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"

    def __eq__(self, other) -> bool:
        return type(self) is type(other) and repr(self) == repr(other)

    def __hash__(self) -> int:
        return hash(repr(self))


class Interval(Domain):
    """The interval ``[a, b]``; points are shaped (n, 1) (or (n,))."""

    name = "interval"
    kind = kernels.INTERVAL

    def __init__(self, a: float = 0.0, b: float = 1.0):
        for name, v in (("a", a), ("b", b)):
            if isinstance(v, bool) or not isinstance(v, numbers.Real):
                raise InvalidArgument(f"Interval({name}={v!r}): must be a real number")
        for name, v in (("a", a), ("b", b)):
            try:
                float(v)
            except OverflowError:   # an int beyond float's range (10**400)
                raise InvalidArgument(f"Interval({name}=...): an integer beyond float64's "
                                      f"range (|{name}| > 1.8e308); need finite a < b with "
                                      "b - a finite") from None
        a, b = float(a), float(b)
        if np.isinf(a) or np.isinf(b):
            raise InvalidArgument(_unbounded_message(a, b))
        # b - a finite too: Interval(-1e308, 1e308) would map parameters to inf
        if not (np.isfinite(a) and np.isfinite(b) and b > a and np.isfinite(b - a)):
            raise InvalidArgument(f"Interval(a={a}, b={b}): need finite a < b with b - a "
                                  "finite")
        with np.errstate(over="ignore"):
            dense = not np.isfinite(1.0 / (b - a))
        if dense:   # Interval(0, 1e-321) was accepted: every density on it overflows
            raise InvalidArgument(f"Interval(a={a}, b={b}): b - a = {b - a:g} is so small "
                                  "that a density on it, 1 / (b - a) and up, overflows "
                                  "float64; scale the variable up")
        self._ends = (a, b)

    # read-only: an interval changed after its checks were planned would be binned with
    # its old width (d.b = 2 made a correct sampler on [0, 2] fail, "pdf integrates to
    # 0.5"); make a new Interval instead
    @property
    def a(self) -> float:
        return self._ends[0]

    @property
    def b(self) -> float:
        return self._ends[1]

    @property
    def jacobian(self) -> float:
        return self._ends[1] - self._ends[0]

    @property
    def args(self):
        return np.array([self.a, self.b])

    def __repr__(self):
        return f"Interval({self.a!r}, {self.b!r})"

    def rounding_edges(self, edges, dtype):
        """Each inner edge moved to halfway between the two neighbouring values of the
        points' ``dtype`` it falls between, where rounding to that type changes its
        answer; edges that meet are merged. A sampler's points are rounded values: a
        cell whose ends fall between them holds a whole number of them, and the rounding
        interval of the value at each end lies partly outside it, so its count is off by
        up to a value's share of the mass while the cubature integrates the pdf over the
        cell as drawn. On ``Interval(1000, 1001)`` (32 float32 values a cell at 512
        cells) a correct float32 sampler failed at p = 4e-9 with 1e6 points (p = 0 on
        ``Interval(1e4, 1e4 + 1)``), and a float64 one on ``Interval(1e9, 1e9 + 1e-3)``
        (16 float64 values a cell: a millisecond at a time in seconds since 1970) at
        p = 4e-76; with these edges each value's rounding interval lies in one cell.
        Float64 points on an interval of more than 2^32 of their values keep the edges
        (a value there is under 1e-9 of a cell's smallest share of 1e-5)."""
        dtype = np.dtype(dtype) if dtype is not None else None
        if dtype not in (np.float32, np.float64) or len(edges[0]) < 3:
            return edges
        a, b = self.a, self.b
        if dtype == np.float64 and (b - a) > 2.0 ** 32 * np.spacing(max(abs(a), abs(b))):
            return edges
        e = np.asarray(edges[0], dtype=np.float64)
        x = a + e[1:-1] * (b - a)
        with np.errstate(over="ignore"):    # an interval beyond float32's range: inf
            v = x.astype(dtype)
        side = np.where(x >= v.astype(np.float64), np.inf, -np.inf).astype(dtype)
        near = np.nextafter(v, side)
        # halfway in the parameter the histogram bins by, (x - a) / (b - a) of each
        s = ((v.astype(np.float64) - a) / (b - a) + (near.astype(np.float64) - a) / (b - a))
        s = np.clip(s / 2.0, 0.0, 1.0)
        return [np.unique(np.concatenate(([0.0], s, [1.0])))]


def _unbounded_message(a: float, b: float) -> str:
    """An infinite end: the domains are bounded (their cells and the cubature map onto
    [0, 1]), and until 7 December a user checking pbrt's ``SampleExponential`` on
    ``Interval(0, inf)`` met "need finite a < b with b - a finite", which said nothing
    of how to check a density on a half line or the real line (an outside review)."""
    return (f"Interval(a={a}, b={b}): an end is infinite, and domains are bounded; check "
            "a density on a half line or the real line on a finite interval that holds "
            "every draw and all its mass but a negligible tail: Interval(0, 40 / λ) for "
            "an exponential of rate λ (-log(1 - u) / λ < 37 / λ for u < 1), "
            "Interval(μ - 9σ, μ + 9σ) for a normal (|erfinv(2u - 1)|·√2 < 8.3)")


class Square(Domain):
    """The unit square ``[0, 1]²``; points (n, 2)."""

    name = "square"
    kind = kernels.SQUARE
    dim = 2
    param_dim = 2
    sample_dim = 2

    def default_resolution(self, n_samples):
        rows = int(np.clip(np.sqrt(max(n_samples // 100, 16)), 4, 90))
        return (rows, rows)


class Disk(Domain):
    """The unit disk; points (x, y). Parameters: ``s0 = r²`` (equal-area rings),
    ``s1 = φ / 2π``; Jacobian π."""

    name = "disk"
    kind = kernels.DISK
    _azimuth_axis = True
    dim = 2
    param_dim = 2
    sample_dim = 2
    jacobian = np.pi

    def default_resolution(self, n_samples):
        rows = int(np.clip(np.sqrt(max(n_samples // 100, 16) / 2.0), 4, 64))
        return (rows, 2 * rows)


class Sphere(Domain):
    """Unit vectors; solid-angle measure. Parameters: ``s0 = (1 - z) / 2`` (equal-area
    bands, Archimedes; computed as ``(x² + y²) / (1 + z) / 2`` for z > 0 and
    ``(2 - (x² + y²) / (1 - z)) / 2`` for z < 0, which keeps float32 points' precision
    near either pole), ``s1 = φ / 2π``; Jacobian 4π."""

    name = "sphere"
    kind = kernels.SPHERE
    _azimuth_axis = True
    dim = 3
    param_dim = 2
    sample_dim = 2
    jacobian = 4.0 * np.pi



class Hemisphere(Sphere):
    """Unit vectors with z ≥ 0. Parameters ``s0 = 1 - z``, ``s1 = φ / 2π``; Jacobian 2π."""

    name = "hemisphere"
    kind = kernels.HEMISPHERE
    jacobian = 2.0 * np.pi


_BY_NAME = {c.name: c for c in (Interval, Square, Disk, Sphere, Hemisphere)}


#: What the numba passes take from a built-in domain's class: an instance or subclass
#: that changes one would be binned as the built-in one (or written past its arrays);
#: ``tolerance`` goes into every pass unvalidated (NaN or 0.5 let points far outside the
#: square in, clamped to its edge without an "outside" failure; a string crashed numba).
_KERNEL_SHAPE = ("kind", "dim", "param_dim", "tolerance")
#: What the numba binning and quadrature passes decide by ``kind`` and ``args``, not by
#: calling the method: a subclass that overrides one would be silently ignored.
_KERNEL_DECIDED = ("classify", "to_param", "inside", "to_point", "binning_edges", "points",
                   "args", "kind", "dim", "param_dim", "jacobian", "_azimuth_axis")
#: The same for an interval: its ends (``args`` and ``jacobian`` are read from the ends
#: it was made with: a subclass returning its own ``a`` and ``b`` was binned on those
#: but measured on the others, and a correct sampler on [360, 830] failed, "pdf
#: integrates to 0.00212766", until 7 December; an outside review).
_INTERVAL_DECIDED = ("a", "b")


def _same(a, b) -> bool:
    """``a == b`` as one bool, False where the comparison is not one (an array)."""
    try:
        return bool(a == b)
    except (TypeError, ValueError):
        return False


def _refuse_custom(domain: Domain) -> None:
    """A clear error for a ``Domain`` the checks cannot honour: a subclass of its own
    geometry (no kernel branch), or one overriding what the kernels decide."""
    concrete = (Hemisphere, Sphere, Interval, Square, Disk)   # Hemisphere before Sphere
    builtin = (Domain,) + concrete
    cls = type(domain)
    # the most derived built-in domain it is
    base = next((b for b in concrete if isinstance(domain, b)), None)
    if base is None:
        raise InvalidArgument(
            f"domain={domain!r}: {cls.__name__} is not one of the built-in domains "
            "(Interval, Square, Disk, Sphere, Hemisphere), which the checks bin and "
            "integrate in numba passes; Domain itself is only their base class")
    try:                        # every message and pass reads these
        repr(domain), domain.args, domain.jacobian
    except AttributeError as e:
        # an Interval subclass whose __init__ skips Interval's has no ends (until
        # 7 December: AttributeError '_ends' from deep inside the check)
        raise InvalidArgument(
            f"domain: {cls.__name__} object is not set up ({e}); its __init__ must call "
            f"{base.__name__}'s (super().__init__(...))") from None
    for name in _KERNEL_SHAPE:
        if not _same(getattr(domain, name), getattr(base, name)):
            raise InvalidArgument(
                f"domain={domain!r}: {cls.__name__} sets {name}={getattr(domain, name)!r}, "
                f"but the checks bin it as the built-in {base.__name__} ({name}="
                f"{getattr(base, name)!r}); subclass a built-in domain for its repr or "
                "default_resolution only")
    # the uniform numbers a sampler on it takes by default: a subclass may set its own
    # (a hemisphere sampler of 3 numbers), but 0 handed samplers (n, 0) arrays of u, a
    # float crashed numpy (until 7 December; an outside review)
    k = domain.sample_dim
    if isinstance(k, bool) or not isinstance(k, numbers.Integral) or k < 1:
        raise InvalidArgument(f"domain={domain!r}: {cls.__name__} sets sample_dim={k!r}, "
                              "but it must be an integer >= 1 (the uniform numbers a "
                              "sampler on it takes by default)")
    changed = [name for name in _KERNEL_DECIDED if name in vars(domain)]
    if changed:
        raise InvalidArgument(
            f"domain={domain!r}: {', '.join(changed)} set on the instance, but the checks "
            f"bin it as the built-in {base.__name__} (they do not read it); make a new "
            "domain instead")
    if cls in builtin:
        return
    for name in _KERNEL_DECIDED + (_INTERVAL_DECIDED if base is Interval else ()):
        owner = next(c for c in cls.__mro__ if name in c.__dict__)
        if owner not in builtin and name in _INTERVAL_DECIDED:
            raise InvalidArgument(
                f"domain: {cls.__name__} overrides {name!r}, but the checks bin and "
                f"measure the interval it was made with, [{domain._ends[0]!r}, "
                f"{domain._ends[1]!r}]: give its ends to Interval.__init__ "
                "(super().__init__(a, b)) instead")
        if owner not in builtin:
            raise InvalidArgument(
                f"domain={domain!r}: {cls.__name__} overrides {name!r}, which the checks "
                "do not call (they bin and integrate in numba passes for the built-in "
                "domains: Interval, Square, Disk, Sphere, Hemisphere); map the samples "
                "to one of those, or subclass one for its repr or default_resolution only")


def why_outside(domain: Domain, x) -> str:
    """What puts the point ``x``, outside ``domain``, there, for a failure message ("" on
    the interval and square, where its coordinates say it): a direction 1e-3 longer
    than 1, z = 0.66, read as "outside the hemisphere" and nothing more, which sent a
    user after the frame, not the normalisation (an outside review)."""
    x = np.asarray(x, dtype=np.float64).ravel()
    tol = domain.tolerance
    if domain.kind in (kernels.SPHERE, kernels.HEMISPHERE) and x.size == 3:
        norm = float(np.sqrt(np.sum(x * x)))
        if abs(norm - 1.0) > tol:
            return f"; its length is {norm:.7g}, not 1 within {tol:g}: normalise the direction"
        if domain.kind == kernels.HEMISPHERE and x[2] < -tol:
            return (f"; its z = {x[2]:.6g} is below the horizon: the hemisphere is z >= 0 "
                    "about the normal, in the local frame (a lobe that transmits is judged "
                    "on the sphere)")
    if domain.kind == kernels.DISK and x.size == 2:
        r = float(np.hypot(x[0], x[1]))
        if r * r > 1.0 + tol:
            return f"; its radius is {r:.7g}, beyond 1"
    return ""


#: Half-spaces a hemisphere's directions may be about in another convention: (axis, sign,
#: the points' half-space, the guess).
_OTHER_UPS = ((1, 1.0, "y >= 0", "a hemisphere about +y (a y-up renderer's)? the checks' "
               "hemisphere is about +z: rotate into the local frame, (x, y, z) -> (x, -z, y)"),
              (0, 1.0, "x >= 0", "a hemisphere about +x? the checks' hemisphere is about "
               "+z: rotate into the local frame"),
              (2, -1.0, "z <= 0", "directions reversed or mirrored in the surface (about "
               "-z, not +z)?"))


def convention_note(domain: Domain, x) -> str:
    """A guess at another renderer's convention where points of one call of the sampler
    (``x``, all its rows) lie outside ``domain``: unit vectors all in another half-space
    than z >= 0, about half of them below the horizon (a y-up cosine lobe), or disk
    points all (r, φ) pairs, r in [0, 1] and φ spanning more than π within [-π, 2π]. Until
    7 December such samplers were told "its z = -0.58 is below the horizon" or "its radius
    is 5.7, beyond 1" and no more (an outside review). "" where nothing fits: a guess
    only for a whole call's points."""
    x = np.asarray(x, dtype=np.float64)
    if x.ndim == 2:
        x = x[~np.isnan(x).all(axis=1)]         # rejected draws (rejection=True)
    if x.ndim != 2 or x.shape[0] < 100 or not np.isfinite(x).all():
        return ""
    tol, n = domain.tolerance, x.shape[0]
    if domain.kind == kernels.HEMISPHERE and x.shape[1] == 3:
        if np.abs(np.sqrt(np.sum(x * x, axis=1)) - 1.0).max() > tol:
            return ""
        below = np.count_nonzero(x[:, 2] < -tol) / n
        for axis, sign, name, why in _OTHER_UPS:
            # about +x or +y: z of both signs, as a lobe about the horizontal axis has
            if (sign * x[:, axis]).min() >= -tol and (axis == 2 or 0.1 <= below <= 0.9):
                return f"; all {n} points of a call have {name}: {why}"
    if domain.kind == kernels.DISK and x.shape[1] == 2:
        r, phi = x[:, 0], x[:, 1]
        for top, (span, two) in ((np.pi, ("π", "2π")), (180.0, ("180", "360"))):
            if r.min() >= 0.0 and r.max() <= 1.0 + tol and phi.min() >= -top \
                    and phi.max() <= 2 * top and phi.max() - phi.min() > top \
                    and (top == np.pi or np.abs(phi).max() > 2 * np.pi):
                unit, of = ("", "") if top == np.pi else (" in degrees", " of np.radians(φ)")
                return (f"; all {n} points of a call have x in [0, 1] and y in [-{span}, "
                        f"{two}]: (r, φ) polar coordinates{unit}? return (r cos φ, "
                        f"r sin φ){of}")
    return ""


def as_domain(domain) -> Domain:
    """A ``Domain`` from a name (``"interval"``, ``"square"``, ``"disk"``, ``"sphere"``,
    ``"hemisphere"``) or a ``Domain`` instance (a built-in one: ``_refuse_custom``)."""
    if isinstance(domain, Domain):
        _refuse_custom(domain)
        return domain
    if isinstance(domain, str) and domain in _BY_NAME:
        return _BY_NAME[domain]()
    raise InvalidArgument(
        f"domain={domain!r}: expected one of {sorted(_BY_NAME)} or a Domain object "
        "such as mcverify.Interval(a, b)" + _domain_hint(domain))


def _domain_hint(domain) -> str:
    """What the user likely meant: an instance where the class was given
    (``domain=mv.Hemisphere``), the name where its case or spaces differ (``"Disk"``);
    until 7 December both met the bare list of names (an outside review)."""
    if isinstance(domain, type) and issubclass(domain, Domain):
        call = "Interval(a, b)" if issubclass(domain, Interval) else f"{domain.__name__}()"
        return f"; that is the class {domain.__name__}, not a domain: pass an instance, {call}"
    if isinstance(domain, str) and domain.strip().lower() in _BY_NAME:
        return f"; did you mean {domain.strip().lower()!r}?"
    return ""
