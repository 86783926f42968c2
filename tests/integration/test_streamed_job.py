"""Streamed jobs in-process: the daemon's controller, the real master and simulated drives on
python-can's virtual bus, the producer planning chunks of 100 set-points (0.4 s at 4 ms) so
every request lands in a job made of many chunks, mid-chunk or at a boundary."""

from __future__ import annotations

import contextlib
import mmap
import os
import signal
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from nurbsmotion.config import parse_config
from nurbsmotion.errors import InputError
from nurbsmotion.service import streamed_job
from nurbsmotion.program import ReadOptions
from nurbsmotion.service.checked_store import CheckedStore
from nurbsmotion.service.controller import Controller
from nurbsmotion.service.link import open_link
from nurbsmotion.service.records import JobRecords
from nurbsmotion.service.planner_worker import PlannerWorker
from nurbsmotion.service.streamed_job import StreamedJob, prepare_streamed_job
from nurbsmotion.service.verify import held_plan_held, planned_counts, recorded_counts
from tests.integration.daemon_helpers import CONFIG
from tests.helpers import memory_of, wait_for

CHUNK = 100
# ~4.5 s at F1200: about 9 chunks, most of them ending while the axes move (a stop tail each)
LONG = "G21 G90\nG01 X40 Y20 F1200\nG01 X0 Y0\n"
WITH_M0 = "G21 G90\nG01 X40 Y20 F1200\nG01 X30 Y10\nM0\nG01 X-20 Y20\nG01 X0 Y0\n"


@contextlib.contextmanager
def streaming_controller(tmp_path: Path, planner_worker: PlannerWorker, store: CheckedStore | None = None,
                         plans: list[StreamedJob] | None = None) -> Iterator[Controller]:
    """The controller on simulated drives, its jobs streamed in CHUNKs (from ``store`` if given);
    each job's plan appended to ``plans``."""
    text = CONFIG.format(channel=f"st-{uuid.uuid4().hex}", socket=tmp_path / "ctl.sock", data_dir=tmp_path / "var")
    config = parse_config(text, str(tmp_path / "machine.yaml"))
    link, simulation = open_link(config)

    def prepare(name: str, text: str, start: np.ndarray, options: ReadOptions) -> StreamedJob:
        plan = prepare_streamed_job(name, text, config, planner_worker, start, options, CHUNK, store=store)
        if plans is not None:
            plans.append(plan)
        return plan

    controller = Controller(config, link, prepare, JobRecords(config.data_dir), simulation)
    try:
        yield controller
    finally:
        controller.shutdown(5.0)
        if simulation is not None:
            simulation.stop()


@pytest.fixture()
def machine(tmp_path, planner_worker):
    with streaming_controller(tmp_path, planner_worker) as controller:
        yield controller


def submit(controller: Controller, text: str, name: str = "long.nc") -> str:
    return controller.submit(name, text)["job"]["id"]


def ended(controller: Controller, job_id: str, timeout_s: float = 30.0) -> dict:
    wait_for(lambda: controller._job is None, timeout_s, "the job's end")
    return controller.job_info(job_id)["job"]


def running_at(controller: Controller, cycle: int) -> dict:
    return wait_for(lambda: (s := controller.status())["job"] and s["job"]["cycle"] >= cycle and s, 20.0,
                      f"cycle {cycle}")


def at_rest_on_path(job: dict, plan: np.ndarray) -> bool:
    """The final set-point lies on the planned polyline and the axes settled there."""
    final = job["outcome"]["final_position"]
    commanded = np.array([final[a]["commanded_mm"] for a in "XYZ"]) * 1000.0
    a, b = plan[:-1].astype(float), plan[1:].astype(float)
    d = b - a
    dd = np.maximum((d * d).sum(axis=1), 1e-12)
    f = np.clip(((commanded - a) * d).sum(axis=1) / dd, 0.0, 1.0)
    distance = np.abs(a + f[:, None] * d - commanded).max(axis=1).min()
    return job["outcome"]["settled"] and distance <= 1.0


def test_a_streamed_job_applies_exactly_the_plan_across_its_chunks(machine):
    job = ended(machine, submit(machine, LONG))
    assert job["outcome"]["outcome"] == "completed", job["outcome"]
    assert job["plan"]["streamed"] and job["plan"]["planned_all"]
    assert job["plan"]["cycles"] > 8 * CHUNK
    assert job["outcome"]["sent"] == job["outcome"]["planned"] == job["plan"]["cycles"]
    folder = Path(job["folder"])
    plan = planned_counts(folder, machine.config)
    recorded, _ = recorded_counts(folder, machine.config)
    assert held_plan_held(recorded, plan)  # every row once, in order, no gap or repeat at a chunk boundary
    assert job["plan"]["measured"]["max_accel_mm_s2"] <= machine.config.interpolation.max_accel_mm_s2 * 1.001


def test_the_path_length_reaches_plan_json_and_the_progress_after_the_first_chunk(machine):
    """The worker measures the blocks' lengths after the first chunk (planner_worker.PathLengths):
    the progress uses them while the job runs, plan.json has the path's length at the end."""
    job_id = submit(machine, LONG)
    running_at(machine, 3 * CHUNK)  # the lengths come with the second chunk at the latest
    job = machine._job
    first_line = np.hypot(40.0, 20.0)
    assert job is not None and job.plan._lengths.before_mm == pytest.approx([0.0, first_line, 2 * first_line], abs=1e-9)
    info = ended(machine, job_id)
    assert info["plan"]["length_mm"] == round(2 * first_line, 6)  # as a whole plan's plan.json


def test_progress_before_the_lengths_is_by_block_then_by_length():
    """The job's own arithmetic: lengths not yet sent, then sent."""
    from nurbsmotion.service.planner_worker import PathLengths

    plan = streamed_job.StreamedJob.__new__(streamed_job.StreamedJob)
    plan.finished, plan.planned, plan._lengths, plan.summary = False, 0, None, {"length_mm": None}
    plan.program = type("P", (), {"blocks": (0, 1, 2, 3)})()
    plan._starts = streamed_job.BlockStarts()
    plan._starts.add(np.array([0, 10, 20]), np.array([0, 1, 2]))
    assert plan.percent_at(15) == 25.0  # block 1 of 4
    plan._take_lengths(PathLengths.of(np.array([1.0, 3.0, 4.0, 2.0])))
    assert plan.percent_at(15) == 10.0 and plan.percent_at(25) == 40.0  # 1 of 10 mm, 4 of 10 mm
    assert plan.summary["length_mm"] == 10.0


# back where it started: the second run starts there too (the store's key includes the start)
ZIGZAG = "G21 G90 F6000\n" + "".join(f"G01 X{i % 2} Y{i * 0.02:.2f}\n" for i in range(1, 120)) + "G01 X0 Y0\nM30\n"


def test_from_a_store_the_daemon_maps_the_checked_program_and_the_worker_writes_blocks_csv(tmp_path, planner_worker):
    """Issue 25 item 4: the checked program reaches the daemon as its store entry, mapped (no
    copy of the blocks in the daemon, whether just checked or loaded), and the job record's
    blocks.csv, every block's line, comes from the worker as it plans. The program's text goes
    to the worker only when it must read it."""
    plans: list[StreamedJob] = []
    with streaming_controller(tmp_path, planner_worker, CheckedStore(tmp_path / "checked", "cfg"), plans) as controller:
        for from_store in (False, True):
            job = ended(controller, submit(controller, ZIGZAG, "zig.nc"))
            assert job["outcome"]["outcome"] == "completed"
            plan = plans[-1]
            assert plan.summary["checked_from_store"] is from_store and len(plan.program.blocks) == 120
            assert isinstance(memory_of(plan.program.blocks.starts), mmap.mmap)
            assert isinstance(memory_of(plan.program.blocks.text.data), mmap.mmap)
            lines = (Path(job["folder"]) / "blocks.csv").read_text().splitlines()
            assert lines == ["line"] + [str(n) for n in range(2, 122)]  # G21 G90 F6000 on line 1
        # the entry is there, so the worker gets the request without the text; damaged, it asks for it
        entry, = (tmp_path / "checked").glob("*.checked")
        entry.write_bytes(entry.read_bytes()[:-8])
        job = ended(controller, submit(controller, ZIGZAG, "zig.nc"))
        assert job["outcome"]["outcome"] == "completed" and plans[-1].summary["checked_from_store"] is False
        assert isinstance(memory_of(plans[-1].program.blocks.starts), mmap.mmap)  # stored again, mapped
    assert len(list((tmp_path / "checked").glob("*.checked"))) == 1


def test_records_are_written_while_the_job_runs(machine):
    job_id = submit(machine, LONG)
    running_at(machine, 6 * CHUNK)
    folder = Path(machine.job_info(job_id)["job"]["folder"])
    trace = folder / "trace.csv.part"
    trace = trace if trace.exists() else folder / "trace.csv"  # the producer may have planned the rest already
    assert (folder / "plan.json").exists() and len(trace.read_text().splitlines()) > 6 * CHUNK
    wait_for(lambda: (folder / "feedback.csv").exists() and (folder / "feedback.csv").stat().st_size > 0, 5.0,
               "feedback rows")
    assert not (folder / "outcome.json").exists()
    ended(machine, job_id)
    assert (folder / "trace.csv").exists() and (folder / "outcome.json").exists()


@pytest.mark.parametrize("cycle", [150, 399, 400, 801])  # mid-chunk and around chunk boundaries
def test_stop_at_any_point_rests_on_the_path(machine, cycle):
    job_id = submit(machine, LONG)
    running_at(machine, cycle)
    machine.stop()
    job = ended(machine, job_id)
    assert job["outcome"]["outcome"] == "stopped" and job["outcome"]["reason"] == "stopped on request"
    assert at_rest_on_path(job, planned_counts(Path(job["folder"]), machine.config))
    assert machine.status()["state"] == "idle"


def test_hold_and_resume_mid_job_complete_every_planned_row(machine):
    job_id = submit(machine, LONG)
    running_at(machine, 5 * CHUNK + 30)
    machine.hold()
    held = wait_for(lambda: (s := machine.status())["state"] == "held" and s, 10.0, "held")
    time.sleep(0.5)  # held across several chunks' worth of time: the producer waits, the axes rest
    assert machine.status()["job"]["cycle"] == held["job"]["cycle"]
    machine.resume()
    job = ended(machine, job_id)
    assert job["outcome"]["outcome"] == "completed"
    assert job["outcome"]["sent"] == job["outcome"]["planned"] == job["plan"]["cycles"]


def test_feed_override_changes_mid_job_and_the_job_completes(machine):
    job_id = submit(machine, LONG)
    running_at(machine, 2 * CHUNK)
    assert machine.override(40.0)["effective_percent"] == 40.0
    time.sleep(1.0)
    machine.override(120.0)
    job = ended(machine, job_id, 60.0)
    assert job["outcome"]["outcome"] == "completed"
    assert [o["requested_percent"] for o in job["outcome"]["overrides"]] == [100.0, 40.0, 120.0]
    assert job["outcome"]["sent"] == job["plan"]["cycles"]


def test_abort_mid_job_quick_stops(machine):
    job_id = submit(machine, LONG)
    running_at(machine, 3 * CHUNK + 50)
    machine.abort()
    job = ended(machine, job_id)
    assert job["outcome"]["outcome"] == "aborted"
    machine.reset()
    assert machine.status()["state"] == "idle"


def test_a_drive_fault_mid_job_ends_it_with_the_fault(machine):
    job_id = submit(machine, LONG)
    running_at(machine, 4 * CHUNK)
    machine.inject_fault("node=2,kind=fault,code=0x2310")
    job = ended(machine, job_id)
    assert job["outcome"]["outcome"] == "fault" and job["outcome"]["fault"]["node"] == 2
    assert (Path(job["folder"]) / "trace.csv").exists()  # the planner stopped and closed its trace
    machine.reset()


def test_a_program_pause_in_a_later_chunk_holds_there_and_resume_completes(machine):
    job_id = submit(machine, WITH_M0)
    paused = wait_for(lambda: (s := machine.status())["state"] == "held" and s, 20.0, "the M0 pause")
    assert paused["job"]["paused"] == "M0 at long.nc:4"
    assert paused["job"]["cycle"] > 2 * CHUNK
    machine.resume()
    job = ended(machine, job_id)
    assert job["outcome"]["outcome"] == "completed"
    assert job["plan"]["pauses"][0]["reason"] == "M0 at long.nc:4"


def test_mdi_runs_as_a_streamed_job(machine):
    answer = machine.mdi("G01 X20 Y-10 F3000")
    job = ended(machine, answer["job"]["id"])
    assert job["outcome"]["outcome"] == "completed" and job["plan"]["streamed"]
    assert job["outcome"]["final_position"]["X"]["commanded_mm"] == pytest.approx(20.0, abs=1e-3)


def test_planning_that_falls_behind_stops_on_the_verified_tail_and_names_the_line(machine, monkeypatch):
    take = streamed_job.StreamedJob._take

    def slow_after_three(self, chunk):
        if chunk.first_row > 0 and self.feed.chunks_taken + self.feed.waiting == 3:
            time.sleep(4.0)  # the fourth chunk arrives late: the axes play three chunks (1.2 s) meanwhile
        take(self, chunk)

    monkeypatch.setattr(streamed_job.StreamedJob, "_take", slow_after_three)
    job = ended(machine, submit(machine, LONG), 40.0)
    outcome = job["outcome"]
    assert outcome["outcome"] == "stopped"
    assert outcome["reason"].startswith("planning fell behind at long.nc:")
    assert 3 * CHUNK < outcome["sent"] < 5 * CHUNK  # three chunks and the third one's stop tail
    folder = Path(job["folder"])
    plan = planned_counts(folder, machine.config)
    recorded, _ = recorded_counts(folder, machine.config)
    end = recorded[-1].astype(float)
    assert outcome["settled"] and (recorded[-3:] == recorded[-1]).all()  # at rest at the end
    # the tail went on along the program's first line from where the plan stopped: X40 Y20 direction
    direction = np.array([40.0, 20.0, 0.0]) / np.hypot(40.0, 20.0)
    along = end / np.linalg.norm(end)
    assert np.allclose(along, direction, atol=1e-3) and np.linalg.norm(end) > np.linalg.norm(plan[-1])


def test_a_soft_limit_beyond_the_path_is_refused_before_any_motion(machine):
    bulge = "G21 G90 G17\nG01 X70 Y-50 F3000\nG03 X70 Y50 I0 J50\n"  # the arc reaches X120 > 100
    before = machine.status()["cycles"]["count"]
    with pytest.raises(InputError) as info:
        machine.submit("arc.nc", bulge)
    assert str(info.value).startswith("arc.nc:3: axis X would reach 120")
    assert machine.status()["state"] == "idle" and machine.status()["job"] is None
    assert machine.status()["cycles"]["count"] >= before


def test_a_planner_worker_killed_mid_job_stops_it_on_its_tail_and_the_next_job_gets_a_new_worker(machine, planner_worker):
    longer = "G21 G90\n" + "G01 X40 Y20 F1200\nG01 X0 Y0\n" * 6  # ~27 s: more chunks than the pipe and queue hold
    job_id = submit(machine, longer)
    running_at(machine, 2 * CHUNK)
    os.kill(planner_worker.pid, signal.SIGKILL)
    job = ended(machine, job_id)
    outcome = job["outcome"]
    assert outcome["outcome"] == "stopped"
    assert outcome["reason"].startswith("long.nc: the planner worker ended unexpectedly (signal 9) after ")
    assert outcome["settled"] and outcome["sent"] < 60 * CHUNK
    plan = planned_counts(Path(job["folder"]), machine.config)
    assert at_rest_on_path(job, plan)
    # a new worker plans it; X5 Y10 is off the path (the stop may end exactly at its reversal X0 Y0:
    # a move there would be refused as no motion, as it was once under load)
    again = ended(machine, machine.mdi("G01 X5 Y10 F3000")["job"]["id"])
    assert again["outcome"]["outcome"] == "completed" and planner_worker.alive


def test_the_worker_parses_with_the_collector_paused_and_restores_it():
    import gc

    from nurbsmotion.runtime import GcQuiet

    assert gc.isenabled()
    with pytest.raises(InputError):
        with GcQuiet("disable"):
            assert not gc.isenabled()
            raise InputError("p.nc:1", "refused")
    assert gc.isenabled()
    gc.disable()
    try:
        with GcQuiet("disable"):
            pass
        assert not gc.isenabled()  # left as it was found
    finally:
        gc.enable()
