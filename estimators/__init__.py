"""The subject: Monte Carlo estimators, warps, distributions and the path tracer."""

from mcnumba.vector_width import prefer_wide_vectors

prefer_wide_vectors()
