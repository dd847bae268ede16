import pytest


@pytest.fixture(scope="session")
def mitsuba():
    """The Mitsuba module with gibench's variant choice (LLVM when usable)."""
    from references.mitsuba_env import load_mitsuba

    return load_mitsuba()
