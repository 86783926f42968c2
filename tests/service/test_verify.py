"""service.verify: a record's planned counts use the axis offsets the job ran with."""

from __future__ import annotations

import json

from nurbsmotion.config import parse_config
from nurbsmotion.service.controller import config_dict
from nurbsmotion.service.verify import offsets_in_force

CONFIG = "axes:\n  - {name: X, node_id: 1, offset_counts: 7}\n  - {name: Y, node_id: 2}\n"


def test_the_record_keeps_the_offsets_in_force_and_verify_reads_them(tmp_path):
    config = parse_config(CONFIG, "m.yaml")
    # homing moved Y's zero (method 'here', or the master's home offset): the record says so
    (tmp_path / "config.json").write_text(json.dumps(config_dict(config, [7, -20_000])))
    assert [a.offset_counts for a in offsets_in_force(tmp_path, config).axes] == [7, -20_000]
    assert [a["offset_counts"] for a in config_dict(config)["axes"]] == [7, 0]  # none given: as configured


def test_a_record_without_config_json_is_read_with_the_configured_offsets(tmp_path):
    config = parse_config(CONFIG, "m.yaml")
    assert offsets_in_force(tmp_path, config) is config
