"""Suite-wide guard: no test may build the default or quick fleet dataset (≈ 2.5 min, ≈ 20 s) or
touch the user's cache. Every test runs with ``$TRAINCLIMATE_HOME`` in a temporary directory and
``trainclimate.data.cache.default_dataset`` and ``quick_dataset`` replaced by a failure; tests that
need data build a small dataset themselves."""

import pytest

from trainclimate.data import cache


@pytest.fixture(autouse=True, scope="session")
def _no_default_dataset(tmp_path_factory):
    def refuse(*args, **kwargs):
        raise AssertionError("a test asked for the default dataset")

    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("TRAINCLIMATE_HOME", str(tmp_path_factory.mktemp("home")))
        mp.setattr(cache, "default_dataset", refuse)
        mp.setattr(cache, "quick_dataset", refuse)
        yield
