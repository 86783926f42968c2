"""service.record_config: a job record's config.json holds every configured value as JSON,
words as the YAML spells them."""

from __future__ import annotations

import json

import pytest

from nurbsmotion.config import load_config
from nurbsmotion.service.record_config import config_dict


@pytest.mark.parametrize("web, expected", [("", "auto"), ("web: {cpus: all}\n", "all"),
                                           ("web: {cpus: [1, 0]}\n", [0, 1])])
def test_the_record_keeps_web_cpus_as_written(tmp_path, web, expected):
    path = tmp_path / "m.yaml"
    path.write_text("axes: [{name: X, node_id: 1}]\n" + web)
    kept = json.loads(json.dumps(config_dict(load_config(path))))
    assert kept["web"]["cpus"] == expected
    assert kept["axes"][0]["name"] == "X"
