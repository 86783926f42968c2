"""Whatever a user sends in whatever order (submit, then at a random moment abort, stop,
override 0-150 %, nothing), every job ends with an outcome in its record, reset always
brings the daemon back to idle, and the drives never applied a set-point step beyond
v_max/a_max, also while the override changed or a stop decelerated."""

from __future__ import annotations

import random
import time

from tests.reliability.rig import assert_records_within_limits
from tests.reliability.test_drive_loss import PERIOD_MS, Running, running  # noqa: F401 - fixture

ROUNDS = 12
OUTCOME_OF = {"abort": {"aborted"}, "stop": {"stopped", "completed"}, "pause": {"stopped"},
              "override": {"completed"}, "none": {"completed"}}


def test_random_command_sequences_never_leave_the_daemon_stuck(running: Running):
    r = running
    rng = random.Random(11)
    for round_ in range(ROUNDS):
        x = rng.uniform(-20.0, 20.0)
        response = r.ask("submit", name="seq.nc", program=f"G21 G90\nG01 X{x:.3f} Y{-x:.3f} Z{x / 4:.3f} F4800\n")
        assert response["ok"], response
        time.sleep(rng.uniform(0.0, 0.2))
        command = rng.choice(list(OUTCOME_OF))
        if command in ("abort", "stop"):
            answer = r.ask(command)
            assert answer["ok"] or "no job is running" in answer["error"], answer
        elif command == "pause":  # override 0 holds on the path; then stop
            assert r.ask("override", percent=0)["ok"]
            assert r.ask("stop")["ok"]
        elif command == "override":
            assert r.ask("override", percent=rng.choice([30, 80, 150]))["ok"]
        outcome = r.outcome(response["job"]["id"])
        expected = OUTCOME_OF[command] | ({"completed"} if command == "abort" else set())  # abort after the end
        assert outcome["outcome"] in expected, (round_, command, outcome)
        assert_records_within_limits(r.recordings(response["job"]["id"]), PERIOD_MS / 1000)
        assert r.ask("override", percent=100)["ok"]
        if r.ask("status")["state"] != "idle":
            assert r.ask("reset")["ok"]
        assert r.ask("status")["state"] == "idle", (round_, command)
