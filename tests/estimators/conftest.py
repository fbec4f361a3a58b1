import pytest


@pytest.fixture(scope="module")
def mi():
    """Mitsuba's scalar variant (pointwise calls), the previous variant restored after."""
    import mitsuba

    before = mitsuba.variant()
    mitsuba.set_variant("scalar_rgb")
    yield mitsuba
    if before:
        mitsuba.set_variant(before)
