"""The subject: Monte Carlo estimators, warps, distributions and the path tracer."""

from mcnumba.disk_cache import cache_in_temporary_folder, tolerate_damaged_cache
from mcnumba.vector_width import prefer_wide_vectors

prefer_wide_vectors()
tolerate_damaged_cache()
cache_in_temporary_folder()
