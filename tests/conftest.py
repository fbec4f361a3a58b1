import os

from hypothesis import HealthCheck, settings

# Hypothesis profiles, as the project's configuration habit: "ci" is derandomised so
# CI is deterministic; "thorough" explores more for nightly runs.
settings.register_profile("ci", derandomize=True, max_examples=40, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("thorough", max_examples=300, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))
