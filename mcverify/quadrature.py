"""Adaptive, vectorised Gauss–Legendre cubature of a density over histogram cells.

The χ² test is only as good as its expected counts. A fixed low-order rule is biased
on cells that a discontinuity crosses (a cone's rim, a triangle's edge, a step of a
piecewise-constant pdf), and the bias grows with the sample count until a correct
sampler fails. Here each cell is integrated with a tensor Gauss–Legendre rule and
compared with the same rule on its 2^m children; where they disagree by more than a
fraction of the cell's Poisson noise, or where the density at a corner of the cell far
exceeds every node value (a boundary layer both rules would miss, such as the tail of
a Beckmann lobe), the children are refined, all cells of one level in one vectorised
batch.

The tolerance is statistical, not absolute: a cell's quadrature error ``δ`` (in counts)
must satisfy ``δ ≤ tau · sqrt(max(E, 5))`` with ``E`` its expected count, so the
quadrature moves the χ² statistic by about ``tau²`` per cell. Across the leaves of a
cell the budget is split as ``2^{-level}`` in 2-D (a discontinuity *curve* cuts about
``2^level`` leaves of a level) and ``2^{-level/2}`` in 1-D (a jump's leaf error halves
per level, so it converges after O(log) levels, and the errors of the successive leaves
at a jump form a geometric series bounded by the cell's budget).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from mcnumba.threads import LOOP, run_ranges

__all__ = ["CellIntegral", "integrate_cells", "gauss_legendre_01", "merge_leaves"]


def gauss_legendre_01(order: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss–Legendre nodes and weights on [0, 1]."""
    x, w = np.polynomial.legendre.leggauss(order)
    return 0.5 * (x + 1.0), 0.5 * w


@dataclass(frozen=True)
class CellIntegral:
    """Integral of the density over each cell.

    ``mass``: shape of the grid; ``error``: the absolute error estimate per cell (sum of
    ``|fine - coarse|`` over its accepted leaves, a conservative bound); ``n_evals``:
    density evaluations used; ``unconverged``: leaves stopped by ``max_level``.
    ``leaves`` (1-D grids only, when asked): ``(lo, width, mass, owner)`` of every
    accepted leaf, sorted by ``lo``, for CDF evaluation inside cells. ``seen``: the least
    and the largest density value read in each cell (at its accepted leaves' nodes and
    corners), shape ``(2,) + grid``; ``(0, inf)`` where a leaf's mass came from nested
    line integrals or the leaf budget ran out, which read more than that. A density value
    in a cell far outside its range (a pilot point's) is a feature the rules never met.
    """

    mass: np.ndarray
    error: np.ndarray
    n_evals: int
    unconverged: int
    leaves: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    seen: np.ndarray | None = None


def merge_leaves(lo, width, mass, owner):
    """1-D leaves as a tuple of arrays sorted by their left end."""
    order = np.argsort(lo, kind="stable")
    return (lo[order], width[order], mass[order], np.asarray(owner)[order].astype(np.int64))


_S_MAX = 1.0 - 2.0 ** -52      # the largest parameter below 1


#: Node values per thread at the least (a few ns each; handing a range of boxes to
#: another thread costs about 50 µs). The box loops are serial ``nogil`` loops that
#: ``mcnumba.threads`` runs on several threads, a range of boxes each: as numba
#: ``prange`` loops they compiled in about twice the time.
_VALUES_PER_THREAD = 16384


@njit(**LOOP)
def _box_points_rows(lo, width, pts, clip, out, i0, i1):
    """``_box_points`` for boxes ``i0`` to ``i1``."""
    n_q, m = pts.shape
    for i in range(i0, i1):
        for q in range(n_q):
            for j in range(m):
                v = lo[i, j] + width[i, j] * pts[q, j]
                out[i * n_q + q, j] = min(max(v, 0.0), _S_MAX) if clip else v


def _box_points(lo, width, pts, clip, out):
    """``out[i·Q + q] = lo[i] + width[i] · pts[q]`` for boxes i and offsets q (one pass:
    numpy built an (L, Q, m) product and a sum, and for corners a clip), clipped to
    [0, 1 - 2^-52] with ``clip``."""
    run_ranges(_box_points_rows, lo.shape[0], lo, width, pts, clip, out,
               grain=max(1, _VALUES_PER_THREAD // pts.shape[0]))


@njit(**LOOP)
def _rule_sums_rows(f, wts, width, out_sum, out_max, out_min, i0, i1):
    """``_rule_sums`` for boxes ``i0`` to ``i1``."""
    n_q = wts.shape[0]
    for i in range(i0, i1):
        acc, hi, lo, nan = 0.0, 0.0, np.inf, False
        for q in range(n_q):
            v = f[i * n_q + q]
            acc += wts[q] * v
            hi = max(hi, v)
            lo = min(lo, v)
            nan |= v != v
        vol = 1.0
        for j in range(width.shape[1]):
            vol *= width[i, j]
        out_sum[i] = acc * vol
        out_max[i], out_min[i] = (np.nan, np.nan) if nan else (hi, lo)


def _rule_sums(f, wts, width, out_sum, out_max, out_min):
    """Per box i: ``Σ_q wts[q] f[i·Q + q] · volume``, and the largest (at least 0) and
    smallest node value; a NaN value makes all three NaN, as numpy's reductions did."""
    run_ranges(_rule_sums_rows, out_sum.shape[0], f, wts, width, out_sum, out_max, out_min,
               grain=max(1, _VALUES_PER_THREAD // wts.shape[0]))


def _tensor(nodes, weights, m):
    """The m-dimensional tensor rule's offsets (q^m, m) and weights (q^m,)."""
    pts = np.stack([g.ravel() for g in np.meshgrid(*([nodes] * m), indexing="ij")], axis=-1)
    wts = np.prod(np.stack(np.meshgrid(*([weights] * m), indexing="ij"), -1)
                  .reshape(-1, m), axis=1)
    return np.ascontiguousarray(pts), np.ascontiguousarray(wts)


def _at_offsets(density, lo, width, pts, clip=False):
    """``density`` at ``lo + width · pts`` of every box, (L · len(pts),)."""
    s = np.empty((lo.shape[0] * pts.shape[0], lo.shape[1]))
    _box_points(np.ascontiguousarray(lo), np.ascontiguousarray(width), pts, clip, s)
    return np.ascontiguousarray(np.asarray(density(s), dtype=np.float64).reshape(-1))


def _rule(density, lo, width, nodes, weights):
    """Tensor Gauss–Legendre integral over boxes ``lo + [0, width]`` (L, m) -> (L,),
    and the largest and smallest density value at the nodes of each box."""
    pts, wts = _tensor(nodes, weights, lo.shape[1])
    f = _at_offsets(density, lo, width, pts)
    out = np.empty((3, lo.shape[0]))
    _rule_sums(f, wts, np.ascontiguousarray(width), out[0], out[1], out[2])
    return out[0], out[1], out[2]


#: A leaf is split only while it is this many ulps wide (of its coordinates) along every
#: axis: the children's Gauss nodes, a few per cent of a child's width from its ends,
#: then stay thousands of ulps apart and off the ends.
_RESOLVABLE = 1e6

#: Corners are sampled this fraction of the leaf inside it: a step lying exactly on a
#: cell edge (a grid-aligned piecewise-constant pdf) then reads this cell's value, not
#: the neighbour's, while any sliver wider than this is still seen.
_CORNER_INSET = 1e-7


def _corner_values(density, lo, width):
    """Density just inside the 2^m corners of each box (Gauss nodes never come near
    them), (L, 2^m) with corner index ``sum(bit_axis << (m - 1 - axis))``."""
    m = lo.shape[1]
    corners = np.ascontiguousarray(np.stack(np.meshgrid(
        *([[_CORNER_INSET, 1.0 - _CORNER_INSET]] * m), indexing="ij"), -1).reshape(-1, m))
    lo, width = np.ascontiguousarray(lo), np.ascontiguousarray(width)
    s = np.empty((lo.shape[0] * corners.shape[0], m))
    _box_points(lo, width, corners, True, s)
    # In a leaf only a few thousand ulps wide the inset rounds away and a corner lands on
    # the leaf's end, which may be a point where the density is singular (a disk's
    # centre under a pdf ∝ 1/r): there the corners sit 16 ulps inside instead.
    ulps = 16.0 * np.spacing(np.abs(lo) + width)
    tiny = np.any(_CORNER_INSET * width < ulps, axis=1)
    if tiny.any():
        near = np.clip(lo[tiny] + ulps[tiny], 0.0, _S_MAX)
        far = np.clip(lo[tiny] + width[tiny] - ulps[tiny], 0.0, _S_MAX)
        bits = corners > 0.5
        fix = np.where(bits[None], far[:, None, :], near[:, None, :])     # (T, 2^m, m)
        s.reshape(lo.shape[0], -1, m)[tiny] = fix
    f = np.asarray(density(s), dtype=np.float64).reshape(-1)
    return np.ascontiguousarray(f).reshape(lo.shape[0], 2 ** m)


def _children(lo, width):
    """Split boxes into 2^m children: (L, m) -> (L * 2^m, m), children contiguous."""
    n_leaves, m = lo.shape
    half = width / 2.0
    corners = np.stack(np.meshgrid(*([[0.0, 1.0]] * m), indexing="ij"), -1).reshape(-1, m)
    c_lo = lo[:, None, :] + half[:, None, :] * corners[None, :, :]
    c_w = np.broadcast_to(half[:, None, :], c_lo.shape)
    return c_lo.reshape(-1, m), np.ascontiguousarray(c_w).reshape(-1, m)


def _spread(values):
    """How much values on a 2 × 2 block of each 2-D leaf, (L, 2, 2) indexed by the bits
    along axis 0 and axis 1, differ along each axis: the largest difference between the
    two halves along axis 0, and along axis 1."""
    return (np.abs(values[:, 1, :] - values[:, 0, :]).max(axis=1),
            np.abs(values[:, :, 1] - values[:, :, 0]).max(axis=1))


def _thin_leaves(density, lo, width, budget, n_samples, tau):
    """Masses of 2-D leaves whose density varies across a feature thinner than the rule
    sees: along the axis where the corner values differ most, a 1-D adaptive integral
    (which resolves a step at any distance from the edge in ~log2(1/distance) cheap
    levels); along the other axis, 3-point Gauss–Legendre (the feature runs across it,
    and these leaves are the smallest of the refinement, so that rule's error is small).

    All leaves' lines are integrated in one batch: line ``k`` is the segment
    ``[k/K, (k+1)/K]`` of one concatenated 1-D axis. Returns the masses, their errors,
    the density evaluations spent and the lines' leaves stopped by the depth limit (an
    integrable singularity along the leaf's edge, x^-0.8 at x = 0: until 7 December not
    counted, so a 2-D check's shortfall came without the depth-limit hint 1-D gives)."""
    n_leaves = lo.shape[0]
    # the corners just inside the leaf, as _corner_values reads them: a corner on the
    # domain's edge may be a point where the density is singular (a disk's centre under
    # a pdf ∝ 1/r), which no integral needs
    f = _corner_values(density, lo, width).reshape(n_leaves, 2, 2)
    across0, across1 = _spread(f)
    j = np.where(across0 >= across1, 0, 1)                # axis the feature varies along
    o = 1 - j
    rows = np.arange(n_leaves)
    nodes, weights = gauss_legendre_01(3)
    leaf = np.repeat(rows, 3)
    n_lines = leaf.size
    # Line k: base_k + t · step_k, t in [0, 1], along axis j of its leaf at node t_o.
    base = lo[leaf].copy()
    base[np.arange(n_lines), o[leaf]] += width[leaf, o[leaf]] * np.tile(nodes, n_leaves)
    step = np.zeros((n_lines, 2))
    step[np.arange(n_lines), j[leaf]] = width[leaf, j[leaf]]
    scale = width[leaf, j[leaf]] * n_lines

    def line_density(t):
        # A line's node within a few ulps of t·K's integer part rounds onto its leaf's
        # end, which on the domain's edge may be where the density is singular: clipped
        # below 1 as the corners are (until 7 December a disk pdf 1 / (2π sqrt(1 - r²)),
        # uniform hemisphere directions projected, was read at r² = 1, 72064 times
        # "NaN/Inf", and a hemisphere's 1 / (4π sqrt(z)) at z = 0; an outside review).
        k = np.minimum((t[:, 0] * n_lines).astype(np.int64), n_lines - 1)
        s = base[k] + (t[:, 0] * n_lines - k)[:, None] * step[k]
        return density(np.clip(s, 0.0, _S_MAX, out=s)) * scale[k]

    # The leaf's mass is Σ_q w_q · width_o · line_q with Σ w_q = 1, so each line may
    # carry an error up to the leaf's budget / width_o.
    r = integrate_cells(line_density, [np.linspace(0.0, 1.0, n_lines + 1)],
                        n_samples=n_samples, tau=tau, max_level=60,
                        noise=budget[leaf] / width[leaf, o[leaf]])
    w_o = width[rows, o]
    line_w = np.tile(weights, n_leaves) * w_o[leaf]
    masses = np.bincount(leaf, weights=r.mass.ravel() * line_w, minlength=n_leaves)
    errors = np.bincount(leaf, weights=r.error.ravel() * line_w, minlength=n_leaves)
    return masses, errors, r.n_evals + 4 * n_leaves, r.unconverged


def integrate_cells(density, edges, *, n_samples: float, tau: float = 0.05,
                    order: int | None = None, max_level: int | None = None,
                    start_level: int = 0, cells=None,
                    keep_leaves: bool = False, max_leaves: int = 4_000_000,
                    noise=None) -> CellIntegral:
    """Integrate ``density(s)`` over the cells of a tensor grid on the unit cube.

    Parameters
    ----------
    density : callable
        ``(N, m) -> (N,)`` density with respect to the parameter measure ``ds``.
    edges : sequence of m increasing 1-D arrays
        Cell boundaries along each parameter axis, from 0 to 1 (need not be uniform).
    n_samples : float
        Sample count the expected counts are for; sets the statistical tolerance.
    tau : float
        Allowed estimated error as a fraction of a cell's Poisson standard deviation.
        0.05: the estimate ``|fine - coarse|`` can undershoot the true error on
        indicator-like densities (measured: 2×), and the true error must stay well
        below 0.15 σ for the χ² statistic to move by < 0.03 per cell.
    order : int, optional
        Gauss–Legendre points per axis: 5 in 1-D (exact for degree 9), 3 in 2-D (exact
        for degree 5 per axis; 9 points per leaf keep refinement along a discontinuity
        curve cheap, and smooth cells still converge at the first level).
    max_level : int, optional
        Deepest refinement (default 40 in 1-D, 9 in 2-D).
    start_level : int
        Subdivide every cell into ``2^(start_level·m)`` leaves before adapting (used to
        re-integrate cells whose density has features narrower than the rule's nodes).
    cells : array of flat cell indices, optional
        Integrate only these cells (others get mass 0).
    keep_leaves : bool
        1-D only: return the accepted leaves for CDF evaluation.
    noise : array, optional
        Error budget per cell in mass units, replacing ``tau × Poisson noise`` (used by
        nested integrals, whose budget comes from the enclosing leaf).
    """
    edges = [np.asarray(e, dtype=np.float64) for e in edges]
    m = len(edges)
    shape = tuple(e.size - 1 for e in edges)
    if max_level is None:
        max_level = 40 if m == 1 else 9
    if order is None:
        order = 5 if m == 1 else 3
    nodes, weights = gauss_legendre_01(order)
    # the share of a leaf, along one axis at one end, beyond its children's outermost
    # Gauss nodes: a step there is seen by neither rule
    band = float(nodes.min()) / 2.0
    lo_axes = np.meshgrid(*[e[:-1] for e in edges], indexing="ij")
    w_axes = np.meshgrid(*[np.diff(e) for e in edges], indexing="ij")
    all_lo = np.stack([g.ravel() for g in lo_axes], -1)
    all_w = np.stack([g.ravel() for g in w_axes], -1)
    owner = np.arange(all_lo.shape[0]) if cells is None else np.asarray(cells, dtype=np.int64)
    lo, width = all_lo[owner], all_w[owner]
    for _ in range(start_level):
        lo, width = _children(lo, width)
        owner = np.repeat(owner, 2 ** m)

    n_cells = int(np.prod(shape))
    mass = np.zeros(n_cells)
    error = np.zeros(n_cells)
    seen_lo, seen_hi = np.full(n_cells, np.inf), np.zeros(n_cells)
    n_evals = 0
    unconverged = 0
    kept = [] if keep_leaves else None

    coarse, _, _ = _rule(density, lo, width, nodes, weights)
    n_evals += coarse.size * order ** m
    # Each cell's noise scale, from its own first estimate.
    cell_counts = np.zeros(n_cells)
    np.add.at(cell_counts, owner, coarse * n_samples)
    # Cells below 5 expected counts are pooled into bins of >= 5 by the χ² test, so
    # their noise scale is at least that of 5 counts.
    if noise is None:
        noise = tau * np.sqrt(np.maximum(np.abs(cell_counts), 5.0)) / n_samples
    else:
        noise = np.broadcast_to(np.asarray(noise, dtype=np.float64), (n_cells,))

    # whether each leaf's parent met its own budget (the start's leaves have none)
    parent_ok = np.zeros(lo.shape[0], dtype=bool)
    level = start_level
    while lo.shape[0]:
        c_lo, c_w = _children(lo, width)
        fine_parts, node_max, node_min = _rule(density, c_lo, c_w, nodes, weights)
        node_max = node_max.reshape(-1, 2 ** m).max(axis=1)
        node_min = node_min.reshape(-1, 2 ** m).min(axis=1)
        corner_f = _corner_values(density, lo, width)
        trough, peak = corner_f.min(axis=1), corner_f.max(axis=1)
        n_evals += fine_parts.size * order ** m + peak.size * 2 ** m
        fine = fine_parts.reshape(-1, 2 ** m).sum(axis=1)
        err = np.abs(fine - coarse)
        budget = noise[owner] * 2.0 ** (-level * max(m - 1, 0.5))
        # A boundary layer: the density at a corner far above (an exponential tail) or
        # far below (a step just before the edge) anything the nodes saw can hide mass
        # that both rules miss; refine while that mass could exceed the budget.
        area = np.prod(width, axis=1)
        # A step of any height in the band between the children's outermost nodes and
        # the leaf's edge: both rules read one side of it only, agree, and miss the mass
        # between the step and the edge, at most the corner's excess over the nodes'
        # range times the band (a step of 1.5 : 0.48 on the square, under the 4× tests
        # above, had made correct samplers fail at n = 2e5 with an error bound of 0).
        outside = np.maximum(np.maximum(peak - node_max, node_min - trough), 0.0)
        hidden = (((peak > 4.0 * node_max) & (peak * area > budget))
                  | ((trough < 0.25 * node_min) & (node_max * area > budget))
                  | (outside * area * band > budget))
        # A leaf whose children's nodes would no longer be distinct floating-point
        # numbers is not split: its nodes would round onto its ends (onto x = 1 near
        # the top of [0, 1], where doubles are coarsest), and a density with an
        # integrable singularity there (the arcsine's 1/√(1 - x)) would be evaluated at
        # the singular point itself.
        bottom = ~np.all(width > _RESOLVABLE * np.spacing(np.abs(lo) + width), axis=1)
        # A leaf whose nodes lie on both sides of the support's edge (a cone's rim crossing
        # it off the axes) is accepted only where its parent met its budget too: the two
        # rules' errors on a step can agree by chance, |fine - coarse| then undershooting
        # the true error 20-40 times, and a correct sun-sized cone 60° from the pole
        # failed the normalisation test on 3 to 4 in 20 seeds of 1e5 samples as
        # 'integrates to 0.99968' (until 7 December, an outside review). So is a leaf whose
        # nodes differ more than 1.5-fold, which a step between two positive densities
        # makes: a correct sun 1e4 times a sky over the hemisphere failed 'integrates to
        # 0.999895' on 6 of 100 seeds of 1e5 samples, a cap 3.9 times the sky on 14 of 40
        # of 1e4 (until 8 December; the second from a read-only review, which found 4-fold
        # too coarse: 3.9 still failed 14 of 40).
        edge = ((node_min <= 0.0) & (node_max > 0.0)) | (node_max > 1.5 * node_min)
        # A leaf whose nodes all read one value, split from a parent that missed its
        # budget, lies beside a step its nodes do not see, which may still bulge into it
        # between its corners, in the band beyond its children's outermost nodes (the rim
        # of a sun 1e4 times the sky, tangent to a leaf's edge, left 2e-4 of the mass
        # unseen at every depth): it is split once more, whose children's nodes reach
        # twice as close to its edges. A smooth pdf's nodes never all agree.
        flat = (node_min >= node_max) & (level > start_level)
        done = (((err <= budget) & ~hidden & (parent_ok | ~(edge | flat)))
                | (level >= max_level) | bottom | ~np.isfinite(err))
        stopped = (level >= max_level) | bottom
        thin = np.zeros_like(done)
        # not converged: a boundary layer, or a rule error above the budget
        unresolved = hidden | ((err > budget) & np.isfinite(err) & ~bottom)
        if m == 2 and unresolved.any():
            # A feature thinner than the leaf's nodes can see (a rim a hair inside a cell
            # edge), or a step the rules see but isotropic refinement resolves only
            # slowly (a cone's rim along a row of cells: every leaf it crosses refined to
            # the depth limit, 65536 of them, 10.9 million evaluations): integrate such
            # leaves as nested 1-D integrals, at once where the corners vary along one
            # axis only (an axis-aligned feature), else, for a boundary layer, when the
            # isotropic refinement has reached its depth limit.
            along0, along1 = _spread(corner_f.reshape(-1, 2, 2))
            aligned = np.minimum(along0, along1) <= 1e-9 * np.maximum(along0, along1)
            # A leaf whose rule error alone is over budget goes only where its corners
            # vary at all (equal corners: a support strictly inside the leaf, which the
            # 3-point rule across the feature would misjudge) and its four children's
            # masses vary along the same axis as its corners (the 36 nodes see no
            # feature across it).
            kid0, kid1 = _spread(fine_parts.reshape(-1, 2, 2))
            kids_along = np.where(along0 >= along1, kid1 <= 1e-9 * kid0, kid0 <= 1e-9 * kid1)
            one_axis = aligned & (np.maximum(along0, along1) > 0) & kids_along
            thin = (((hidden & aligned) | (unresolved & one_axis)) & (level >= 2)) \
                | (hidden & (level >= max_level))
            if thin.any():
                fine = fine.copy()
                fine[thin], err[thin], spent, stuck = _thin_leaves(
                    density, lo[thin], width[thin], budget[thin], n_samples, tau)
                done = done | thin
                n_evals += spent
                unconverged += stuck
        unconverged += int(np.count_nonzero(stopped & (err > budget) & ~thin))
        # Where a corner jumps beyond the nodes' own range (a step in the band), both
        # rules may miss the sliver between the step and the edge, which |fine - coarse|
        # does not see: its bound joins the leaf's error (a step at x = 0.4 of a 2y
        # density on the square, a hair right of a leaf's midpoint in every cell it
        # crosses, missed 2e-4 of the mass with an error bound of 1.6e-7, and the
        # normalisation test failed the correct pdf on 12 % of seeds). A converged leaf's
        # sliver is within its budget (the test above). A stopped leaf (at the depth
        # limit) gets none: its error counts as unconverged where it exceeds the budget,
        # not otherwise, and an integrable singularity's corner is unbounded (x^-0.95
        # got a bound of 5). Such a leaf is at floating point's resolution.
        step = (outside > node_max - node_min) & ~thin & ~stopped
        sliver = np.where(step, outside * area * band, 0.0)
        np.add.at(mass, owner[done], fine[done])
        np.add.at(error, owner[done], err[done] + sliver[done])
        read_lo = np.where(thin, 0.0, np.minimum(node_min, trough))
        read_hi = np.where(thin, np.inf, np.maximum(node_max, peak))
        np.minimum.at(seen_lo, owner[done], read_lo[done])
        np.maximum.at(seen_hi, owner[done], read_hi[done])
        if kept is not None and done.any():
            c_mass = fine_parts.reshape(-1, 2 ** m)[done].ravel()
            kept.append((c_lo.reshape(-1, 2 ** m, m)[done].reshape(-1, m)[:, 0],
                         c_w.reshape(-1, 2 ** m, m)[done].reshape(-1, m)[:, 0], c_mass,
                         np.repeat(owner[done], 2 ** m)))
        refine = ~done
        if not refine.any():
            break
        sel = np.repeat(refine, 2 ** m)
        parent_ok = np.repeat((err <= budget)[refine], 2 ** m)
        lo, width = c_lo[sel], c_w[sel]
        coarse = fine_parts[sel]
        owner = np.repeat(owner[refine], 2 ** m)
        level += 1
        if lo.shape[0] > max_leaves:
            # Out of budget: accept the current children as they are.
            np.add.at(mass, owner, coarse)
            seen_lo[owner], seen_hi[owner] = 0.0, np.inf
            unconverged += lo.shape[0]
            if kept is not None:
                kept.append((lo[:, 0], width[:, 0], coarse, owner))
            break

    leaves = None
    if kept is not None:
        cols = [np.concatenate([k[i] for k in kept]) if kept else np.zeros(0)
                for i in range(4)]
        leaves = merge_leaves(*cols)
    seen = np.stack([seen_lo, seen_hi]).reshape((2,) + shape)
    return CellIntegral(mass.reshape(shape), error.reshape(shape), n_evals, unconverged, leaves,
                        seen)
