"""Checks: draw seeded samples from a subject, reduce them with ``stats``, return a
``CheckResult``. Nothing prints; results are data."""

from .estimator import check_convergence, check_unbiased, check_variance
from .consistency import check_pdf_consistency
from .image import compare_images
from .sampler import (check_inverse, check_same_distribution, check_sampler,
                      detectable_contamination)
from .stability import check_stability

__all__ = ["check_sampler", "check_inverse", "check_same_distribution",
           "detectable_contamination",
           "check_unbiased", "check_variance", "check_convergence", "compare_images",
           "check_stability", "check_pdf_consistency"]
