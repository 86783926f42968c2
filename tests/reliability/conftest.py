"""The long variants here (marked ``slow``) run only when asked for: ``pytest -m slow tests/reliability``."""

from pathlib import Path

import pytest

HERE = Path(__file__).parent


def pytest_collection_modifyitems(config, items):
    if "slow" in (config.getoption("-m") or ""):
        return
    skip = pytest.mark.skip(reason="long variant: run with -m slow")
    for item in items:
        if "slow" in item.keywords and HERE in Path(item.path).parents:  # this folder's tests only
            item.add_marker(skip)
