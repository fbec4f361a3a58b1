import os

from hypothesis import HealthCheck, settings

# The path tracer renders with its general kernel in the tests (render(general=None)
# reads this; subprocesses inherit it): one numba compilation serves every scene, where
# each scene's specialised kernel costs about a minute on a new machine. The slow test
# test_every_scenes_specialised_kernel_matches_the_general_one holds every reference
# scene's specialised kernel to the general one bit for bit.
os.environ.setdefault("MCVERIFY_GENERAL_KERNEL", "1")

# Hypothesis profiles, as the project's configuration habit: "ci" is derandomised so
# CI is deterministic; "thorough" explores more for nightly runs.
settings.register_profile("ci", derandomize=True, max_examples=40, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("thorough", max_examples=300, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))
