"""Job records keep the program and plan before motion and the outcome after it."""

import json

import pytest

from nurbsmotion.service.records import JobRecords


def test_a_job_folder_holds_program_plan_trace_and_outcome(tmp_path):
    records = JobRecords(tmp_path)
    record = records.create("part.nc", "G01 X1\n")
    record.write_plan({"cycles": 3}, lambda path: path.write_text("t,x\n"))
    assert (record.folder / "program.nc").read_text() == "G01 X1\n"
    assert record.plan() == {"cycles": 3}
    assert (record.folder / "trace.csv").read_text() == "t,x\n"
    assert record.outcome() is None
    record.write_outcome({"outcome": "completed"})
    assert json.loads((record.folder / "outcome.json").read_text())["outcome"] == "completed"
    assert records.find(record.job_id) == record
    assert record.folder.parent == tmp_path / "jobs"


def test_unknown_outcomes_are_refused(tmp_path):
    record = JobRecords(tmp_path).create("a.nc", "")
    with pytest.raises(ValueError):
        record.write_outcome({"outcome": "fine"})


def test_jobs_without_outcome_are_marked_interrupted_at_start(tmp_path):
    records = JobRecords(tmp_path)
    ended = records.create("a.nc", "x")
    ended.write_outcome({"outcome": "stopped"})
    left = records.create("b.nc", "y")
    assert records.mark_interrupted() == [left]
    assert left.outcome()["outcome"] == "interrupted"
    assert ended.outcome()["outcome"] == "stopped"
    assert records.mark_interrupted() == []


def test_find_refuses_names_that_are_not_job_ids(tmp_path):
    records = JobRecords(tmp_path)
    records.create("a.nc", "x")
    assert records.find("../..") is None and records.find("*") is None


def test_records_list_in_submission_order_within_one_second(tmp_path):
    records = JobRecords(tmp_path)
    made = [records.create(f"{i}.nc", "x") for i in range(5)]  # ids are random: the name must order them
    assert records.all() == made
    assert made[0].created_at[:4].isdigit() and "." in made[0].created_at


def test_a_rejected_submission_keeps_its_program_and_errors(tmp_path):
    records = JobRecords(tmp_path)
    record = records.create_rejected("bad.nc", "G01 Q7\n", ["bad.nc:1: Q7: unsupported word Q"])
    assert record.outcome()["outcome"] == "rejected" and record.outcome()["errors"] == ["bad.nc:1: Q7: unsupported word Q"]
    assert record.summary()["name"] == "bad.nc" and records.mark_interrupted() == []


def test_a_streamed_job_left_mid_plan_gets_its_cycles_from_the_whole_trace_rows(tmp_path):
    records = JobRecords(tmp_path)
    record = records.create("long.nc", "G01 X60\n")
    record.write_plan_summary({"streamed": True, "cycles": None, "period_s": 0.001})
    (record.folder / "trace.csv.part").write_text("t,x\n0,0\n0.001,0.5\n0.002,1.0\n0.00")  # killed mid-line
    assert records.mark_interrupted() == [record]
    assert (record.folder / "trace.csv").read_text() == "t,x\n0,0\n0.001,0.5\n0.002,1.0\n"
    assert not (record.folder / "trace.csv.part").exists()
    plan = record.plan()
    assert plan["cycles"] == 3 and plan["planned_all"] is False and plan["duration_s"] == 0.002


def test_a_whole_plan_record_is_left_as_written(tmp_path):
    records = JobRecords(tmp_path)
    record = records.create("a.nc", "G01 X1\n")
    record.write_plan({"cycles": 2}, lambda path: path.write_text("t,x\n0,0\n0.001,1\n"))
    records.mark_interrupted()
    assert record.plan() == {"cycles": 2}


def test_record_folders_are_absolute_whatever_the_daemons_working_directory(tmp_path, monkeypatch):
    """A client's working directory is not the daemon's: 'var/demo/jobs/...' named the wrong place."""
    monkeypatch.chdir(tmp_path)
    records = JobRecords("var/demo")
    record = records.create("a.nc", "G01 X1\n")
    assert record.folder.is_absolute() and record.folder.parent == tmp_path / "var" / "demo" / "jobs"
    assert records.listing()["root"] == str(tmp_path / "var" / "demo" / "jobs")
    assert records.info(record.job_id)["folder"] == str(record.folder)


def test_an_interrupted_job_names_the_line_and_positions_its_files_show(tmp_path):
    """The daemon died mid-job: the record says where the drives were last (issue 26.6)."""
    records = JobRecords(tmp_path)
    record = records.create("part.nc", "G21 G90\nG01 X1 F600\nG01 X2 Y1\n")
    record.write_block_lines([2, 3])
    record.write_plan_summary({"program": "part.nc", "streamed": False, "cycles": 5})
    (record.folder / "trace.csv").write_text("t,block,u,x,y,z\n0,0,0,0,0,0\n0.004,0,0.5,0.5,0,0\n0.008,0,1,1,0,0\n"
                                             "0.012,1,0.5,1.5,0.5,0\n0.016,1,1,2,1,0\n")
    (record.folder / "feedback.csv").write_text(
        "job_cycle,axis,node,statusword,position_counts,position_mm,time_s\n-1,X,1,4663,0,0.000000,0.0\n"
        "2,X,1,4663,990,0.990000,0.01\n2,Y,2,4663,0,0.000000,0.01\n3,X,1,4663,1480,1.480000,0.014\n"
        "3,Y,2,4663,490,0.49")  # the daemon died writing this line
    assert records.mark_interrupted() == [record]
    outcome = record.outcome()
    assert outcome["outcome"] == "interrupted"
    assert outcome["line_reached"] == {"where": "part.nc:3", "line": 3, "text": "G01 X2 Y1", "block": 1, "setpoint": 3}
    assert outcome["final_position"] == {"X": {"commanded_mm": 1.5, "actual_mm": 1.48},
                                         "Y": {"commanded_mm": 0.5, "actual_mm": 0.0}}
    assert outcome["settled"] is False and "feedback.csv" in outcome["reached_from"]


def test_an_interrupted_job_without_feedback_says_nothing_it_does_not_know(tmp_path):
    records = JobRecords(tmp_path)
    record = records.create("part.nc", "G01 X1 F600\n")
    assert records.mark_interrupted() == [record]
    assert record.outcome()["line_reached"] is None and record.outcome()["final_position"] is None
