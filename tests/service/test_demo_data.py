"""The packaged demo files are the repository's config/demo.yaml and examples/wang_table1.nc."""

from pathlib import Path

import pytest

from nurbsmotion import data

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("name, original", [("demo.yaml", "config/demo.yaml"),
                                            ("wang_table1.nc", "examples/wang_table1.nc")])
def test_packaged_copy_equals_the_repository_file(name, original):
    assert data.read_text(name) == (ROOT / original).read_text(encoding="utf-8")
