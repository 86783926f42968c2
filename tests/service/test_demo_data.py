"""The packaged demo files are copies of the repository's config, example program and EDS."""

from pathlib import Path

import pytest

from nurbsmotion import data

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("name, original", [("demo.yaml", "config/demo.yaml"),
                                            ("wang_table1.nc", "examples/wang_table1.nc"),
                                            ("nurbsmotion-servo.eds", "eds/nurbsmotion-servo.eds")])
def test_packaged_copy_equals_the_repository_file(name, original):
    assert data.read_text(name) == (ROOT / original).read_text(encoding="utf-8")
