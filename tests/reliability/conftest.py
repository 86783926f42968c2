"""The long variants (marked ``slow``) run only when asked for: ``pytest -m slow tests/reliability``."""

import pytest


def pytest_collection_modifyitems(config, items):
    if "slow" in (config.getoption("-m") or ""):
        return
    skip = pytest.mark.skip(reason="long variant: run with -m slow")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)
