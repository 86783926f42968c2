"""feedback.csv: one row per TPDO1, job-relative cycles, positions in counts and mm."""

import csv

from nurbsmotion.axes import AxisMap
from nurbsmotion.config import parse_config
from nurbsmotion.fieldbus.cycle_slack import CycleSlack, SlackWork
from nurbsmotion.service.feedback import HEADER, FeedbackLog

AXES = ("axes:\n  - {name: X, node_id: 4, counts_per_mm: 1000, offset_counts: 500}\n"
        "  - {name: Z, node_id: 7, counts_per_mm: 200, invert: true}\n")


def test_rows_are_written_per_tpdo_with_the_axis_scale_and_the_job_cycle(tmp_path):
    log = FeedbackLog(tmp_path / "feedback.csv", AxisMap.from_config(parse_config(AXES, "m.yaml")))
    log.add(99, 0, 0x0237, 1500, 50.000)  # before the job's cycle 0: the axes still held
    log.add(100, 1, 0x1237, 400, 50.001)
    log.flush(100)
    log.add(101, 1, 0x1237, 410, 50.002)
    log.add(101, 1, 0x1237, 420, 50.0025)  # two answers within one master cycle: both kept
    log.close(100)
    log.flush(100)  # after close: nothing, no error
    text = (tmp_path / "feedback.csv").read_text()
    assert text.startswith(HEADER)
    rows = list(csv.DictReader(text.splitlines()))
    assert [(r["job_cycle"], r["axis"], r["node"], r["statusword"], r["position_counts"]) for r in rows] == [
        ("-1", "X", "4", str(0x0237), "1500"), ("0", "Z", "7", str(0x1237), "400"),
        ("1", "Z", "7", str(0x1237), "410"), ("1", "Z", "7", str(0x1237), "420")]
    assert [float(r["position_mm"]) for r in rows] == [1.0, -2.0, -2.05, -2.1]
    assert [round(float(r["time_s"]), 4) for r in rows] == [0.0, 0.001, 0.002, 0.0025]
    assert log.rows == 4


def test_lines_formatted_in_steps_are_the_samples_received_before_the_first_step(tmp_path):
    log = FeedbackLog(tmp_path / "feedback.csv", AxisMap.from_config(parse_config(AXES, "m.yaml")))
    for k in range(5):
        log.add(10 + k, 0, 0x0237, 1500 + k, 50.0 + k * 1e-3)
    steps = log.line_steps(10, rows_per_step=2)
    next(steps)  # a sample received from here on waits for the next flush
    log.add(15, 0, 0x0237, 1505, 50.005)
    chunks: list[bytes] = []
    try:
        while True:
            next(steps)
    except StopIteration as end:
        chunks = end.value
    assert [c.count(b"\n") for c in chunks] == [2, 2, 1]  # two lines a step
    log.write(chunks)
    log.close(10)
    rows = list(csv.DictReader((tmp_path / "feedback.csv").read_text().splitlines()))
    assert [r["job_cycle"] for r in rows] == ["0", "1", "2", "3", "4", "5"]  # the late one by close
    assert log.rows == 6


class SubmitsSeen(CycleSlack):
    """A slack without a cycle thread that notes how work was submitted (run_steps then runs it)."""

    def __init__(self) -> None:
        super().__init__()
        self.bulk: list[bool] = []

    def submit(self, steps, bulk: bool = False) -> SlackWork | None:  # type: ignore[no-untyped-def]
        self.bulk.append(bulk)
        return None


def test_the_lines_go_to_the_slack_as_bulk_work(tmp_path):
    log = FeedbackLog(tmp_path / "feedback.csv", AxisMap.from_config(parse_config(AXES, "m.yaml")))
    log.add(10, 0, 0x0237, 1500, 50.0)
    slack = SubmitsSeen()
    log.flush(10, slack)
    log.close(10, slack)
    assert slack.bulk == [True, True]  # run when no status answer or round is queued
    assert log.rows == 1
