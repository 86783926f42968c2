"""service.verify: a record's planned counts use the axis offsets the job ran with; and
rest_waits: the drives applied the plan, each row once, in order, held only before, after,
and where the plan itself rests (a streamed job waiting at rest for its next chunk, which a
loaded host makes common: the demo called that 'a DIFFERENT sequence')."""

from __future__ import annotations

import json

import numpy as np

from nurbsmotion.config import parse_config
from nurbsmotion.service.record_config import config_dict
from nurbsmotion.service.verify import offsets_in_force, rest_waits

CONFIG = "axes:\n  - {name: X, node_id: 1, offset_counts: 7}\n  - {name: Y, node_id: 2}\n"
# 1-axis plan: moves 0 -> 3, rests at 3 (two equal rows), moves on to 5
PLAN = np.array([[0], [1], [3], [3], [4], [5]])


def test_the_record_keeps_the_offsets_in_force_and_verify_reads_them(tmp_path):
    config = parse_config(CONFIG, "m.yaml")
    # homing moved Y's zero (method 'here', or the master's home offset): the record says so
    (tmp_path / "config.json").write_text(json.dumps(config_dict(config, [7, -20_000])))
    assert [a.offset_counts for a in offsets_in_force(tmp_path, config).axes] == [7, -20_000]
    assert [a["offset_counts"] for a in config_dict(config)["axes"]] == [7, 0]  # none given: as configured


def test_a_record_without_config_json_is_read_with_the_configured_offsets(tmp_path):
    config = parse_config(CONFIG, "m.yaml")
    assert offsets_in_force(tmp_path, config) is config


def test_the_plan_held_before_and_after_has_no_waits():
    assert rest_waits(np.array([[0], [0], [1], [3], [3], [4], [5], [5]]), PLAN) == 0


def test_holding_where_the_plan_rests_counts_the_cycles_waited():
    assert rest_waits(np.array([[0], [1], [3], [3], [3], [3], [4], [5]]), PLAN) == 2


def test_holding_during_motion_is_not_the_plan():
    assert rest_waits(np.array([[0], [1], [1], [3], [3], [4], [5]]), PLAN) is None


def test_a_skipped_or_foreign_row_is_not_the_plan():
    assert rest_waits(np.array([[0], [3], [3], [4], [5]]), PLAN) is None
    assert rest_waits(np.array([[0], [1], [3], [3], [4], [4.5], [5]]), PLAN) is None
    assert rest_waits(np.array([[0], [1], [3]]), PLAN) is None  # ended early
