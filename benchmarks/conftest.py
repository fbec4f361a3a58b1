"""pytest-benchmark suites (not part of `make test`): `make bench`.

Save a baseline with `--benchmark-save=NAME`; catch a speed regression later with
`--benchmark-compare=NAME --benchmark-compare-fail=min:20%`.
"""

import pytest


def pytest_collection_modifyitems(items):
    for item in items:
        item.add_marker(pytest.mark.benchmark_suite)
