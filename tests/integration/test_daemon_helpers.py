"""The daemon tests' own helpers, checked against the status the daemon's controller gives."""

from __future__ import annotations

from tests.helpers import wait_for
from tests.integration.daemon_helpers import job_reached
from tests.integration.test_streamed_job import CHUNK, LONG, ended, machine, submit  # noqa: F401 (fixture)


def test_a_fraction_of_a_streamed_job_is_reached_only_at_that_fraction_of_its_rows(machine):  # noqa: F811
    """A fault injected at "30 % of the job" was recorded at job cycle 0 (CI, loaded host,
    docs/reliability.md flake 7): the wait had taken 30 % of the rows planned so far, which
    5 ms after the start of a streamed job is 30 % of its first rows."""
    job_id = submit(machine, LONG)
    status = wait_for(lambda: s if job_reached(s := machine.status(), 0.3) else None, 30.0, "30 % of the job",
                      poll_s=0.001)
    planned = ended(machine, job_id)["plan"]["cycles"]
    assert planned > 8 * CHUNK  # many chunks: the first ones were all the status knew at first
    assert status["job"]["cycle"] >= 0.3 * planned
