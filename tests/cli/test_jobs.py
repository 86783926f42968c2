"""cli.jobs: `nurbsmotion job ID` shows a record whole, also while a streamed job runs."""

from __future__ import annotations

from nurbsmotion.cli.jobs import show_lines

STREAMED_RUNNING = {  # what the daemon answers for a streamed job before its planner reached the end
    "id": "a1b2c3d4", "folder": "/var/lib/nurbsmotion/jobs/a1b2c3d4", "running": True,
    "plan": {"program": "wang_x460.nc", "blocks": 460, "length_mm": None, "cycles": None, "duration_s": None,
             "algorithm": "lookahead"},
    "outcome": {"started_at": "2026-11-25T02:57:00.000Z", "motion_time_s": None},
    "files": ["program.nc", "plan.json"],
}


def test_a_running_streamed_job_shows_dashes_for_what_is_not_known_yet():
    lines = show_lines(STREAMED_RUNNING)
    assert "outcome     running" in lines
    assert "plan        460 blocks, - mm, - cycles, - s (lookahead)" in lines
    assert any(line.startswith("time        2026-11-25T02:57:00.000Z ..") and line.endswith("(- s)") for line in lines)


def test_a_finished_job_shows_its_figures():
    job = dict(STREAMED_RUNNING, running=False,
               plan=dict(STREAMED_RUNNING["plan"], length_mm=12345.6789, cycles=3437560, duration_s=3437.56),
               outcome={"outcome": "completed", "started_at": "a", "ended_at": "b", "motion_time_s": 3473.0,
                        "sent": 3437560, "planned": 3437560, "late_cycles": 0, "missed_cycles": 0})
    lines = show_lines(job)
    assert "plan        460 blocks, 12345.679 mm, 3437560 cycles, 3437.560 s (lookahead)" in lines
    assert "time        a .. b (3473.00 s)" in lines
