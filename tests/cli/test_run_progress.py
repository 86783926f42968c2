"""The progress line of ``run`` shows the override and the program line (issue 15.4)."""

from nurbsmotion.cli.run import describe_outcome, progress_text

STATUS = {"state": "running", "axes": [{"name": "X", "commanded_mm": 12.5}],
          "job": {"percent": 16.6, "cycle": 76, "total": 459, "feed_mm_s": 25.0, "override_percent": 50.0,
                  "line": "part.nc:7"}}


def test_the_progress_line_shows_the_override_and_the_line():
    assert progress_text(STATUS) == " 16.6 %  cycle 76/459  feed 25.0 mm/s  override 50 %  part.nc:7  X 12.500  [running]"


def test_an_unfinished_outcome_names_the_line_reached():
    info = {"id": "ab12", "folder": "/r", "outcome": {"outcome": "stopped", "sent": 80, "planned": 459,
                                                       "motion_time_s": 1.0, "reason": "stopped on request",
                                                       "line_reached": {"where": "part.nc:7"}}}
    assert describe_outcome(info).splitlines()[0] == \
        "job ab12 stopped: 80/459 set-points in 1.00 s, reached part.nc:7; stopped on request"


def test_the_progress_line_says_held_and_why():
    held = {**STATUS, "state": "held", "job": {**STATUS["job"], "paused": "M6 tool change to T3 at part.nc:20"}}
    assert progress_text(held).endswith("[held: M6 tool change to T3 at part.nc:20 (resume to continue)]")
    by_request = {**STATUS, "state": "held", "job": {**STATUS["job"], "paused": None}}
    assert progress_text(by_request).endswith("[held]")
