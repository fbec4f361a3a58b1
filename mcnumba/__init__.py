"""numba plumbing that the subject (``estimators``) and the judge (``mcverify``) share.

No Monte Carlo here, and nothing either package computes: how numba's code is generated
(``vector_width``: 512-bit vectors on AVX-512 hosts; ``disk_cache``: a damaged cache file
is a miss) and how a compiled loop runs on
several threads (``threads``: contiguous ranges on a thread pool, instead of numba's
``prange``, whose parfor passes make a loop compile about twice as long). The judge's core
may not import the subject (``tests/test_layers.py``), so what both need lives here, once;
this package imports neither of them.
"""
