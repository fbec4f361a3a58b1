"""pytest-benchmark over the workloads of ``mcverify.gate.bench.pairs()``: the same callables
``mcverify bench`` times, here with saved baselines and regression comparison. Each
group holds ours and Mitsuba's row on the same work; read the ratio column."""

import pytest

from mcverify.gate import bench

PAIRS = bench.pairs()


@pytest.mark.parametrize("side", ["ours", "mitsuba"])
@pytest.mark.parametrize("group", [p[0] for p in PAIRS])
def test_workload(benchmark, group, side):
    _, _, ours, theirs, _ = next(p for p in PAIRS if p[0] == group)
    fn = ours if side == "ours" else theirs
    if fn is None and side == "mitsuba" and group.startswith("render-check"):
        pytest.skip("the render gate has no Mitsuba counterpart")
    if fn is None:
        pytest.skip("Mitsuba's vectorised llvm variant is unavailable here (libLLVM >= 16)")
    # "mitsuba" is the other side: Mitsuba, or the general kernel for the specialisation row
    benchmark.group = group
    benchmark.pedantic(fn, rounds=3, warmup_rounds=1)
