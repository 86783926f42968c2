"""The spindle drive and machine I/O through the daemon, in-process, with the simulated
drives, spindle and CiA-401 node on a private virtual bus: M3/M4/S/M5 with 'at speed' waits,
coolant outputs, e-stop and limit inputs, job end and abort stopping everything, records."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from nurbsmotion.cli.status import format_status
from nurbsmotion.errors import InputError
from nurbsmotion.service.daemon import Daemon
from tests.integration.daemon_helpers import daemon_in_process, subprocess_environment
from tests.helpers import wait_for

SPINDLE_IO = """\
spindle: {node_id: 5, counts_per_rev: 4096, max_rpm: 12000, accel_rpm_s: 20000, at_speed_timeout_s: 3.0}
io:
  node_id: 10
  inputs: {estop: {bit: 0, active_low: true}, limit_x_max: 1}
  outputs: {coolant_flood: 0, coolant_mist: 1, clamp: 4}
"""
MILL = "G21 G90\nS6000 M3\nM8\nG01 X5 F3000\nS9000\nG01 X10\nM5 M9\nG01 X0\nM30\n"


@pytest.fixture
def machine(tmp_path: Path) -> Iterator[Daemon]:
    with daemon_in_process(tmp_path / "data", SPINDLE_IO, "sp") as daemon:
        yield daemon


def sim(daemon: Daemon):
    return daemon.simulation.network  # type: ignore[union-attr]


def spindle_rpm(daemon: Daemon) -> float:
    return sim(daemon)[5].axis.velocity_actual * 60.0 / 4096


def wait_job(daemon: Daemon, job_id: str, timeout_s: float = 30.0) -> dict:
    assert daemon.controller is not None
    return wait_for(lambda: (info := daemon.controller.job_info(job_id)["job"]).get("outcome") and info, timeout_s,
                      f"job {job_id} end")


def test_a_mill_program_waits_for_the_spindle_switches_coolant_and_stops_both_at_the_end(machine):
    controller = machine.controller
    assert controller.status()["spindle"]["commanded_rpm"] == 0
    wait_for(lambda: controller.status()["spindle"]["actual_rpm"] is not None, 2.0, "first 0x606C read")
    lines = format_status(controller.status())
    assert "spindle node 5: OPERATION ENABLED, commanded 0 rpm, actual 0 rpm, at speed" in lines
    assert "io node 10: inputs active none, outputs on none" in lines
    job = controller.submit("mill.nc", MILL)["job"]["id"]
    status = wait_for(lambda: (s := controller.status())["job"] and s["job"]["paused"] and s, 10.0, "spindle wait")
    assert "S6000 M3" in status["job"]["paused"] or "M3 at mill.nc:2" in status["job"]["paused"]
    assert abs(status["axes"][0]["commanded_mm"]) < 1e-9  # nothing moved before the spindle is at speed
    info = wait_job(machine, job)
    outcome = info["outcome"]
    assert outcome["outcome"] == "completed", outcome["reason"]
    events = [(e["code"], e.get("rpm"), e.get("at_speed")) for e in outcome["machine_events"] if "code" in e]
    assert events[:2] == [("M3", 6000.0, True), ("M8", None, None)]
    assert ("S9000", 9000.0, True) in events and ("M5", 0.0, None) in events and ("M9", None, None) in events
    log_lines = (Path(info["folder"]) / "events.log").read_text().splitlines()
    assert len(log_lines) == len(outcome["machine_events"]) and log_lines[0].startswith("spindle_event ")
    assert sim(machine).io_nodes[10].outputs == b"\x00"  # coolant off after M9 and at the end
    wait_for(lambda: spindle_rpm(machine) == 0, 5.0, "spindle at rest after M5")


def test_the_flood_output_is_on_between_m8_and_m9(machine):
    controller = machine.controller
    job = controller.submit("c.nc", "G21 G90\nM8\nG01 X20 F600\nM9\n")["job"]["id"]
    wait_for(lambda: sim(machine).io_nodes[10].outputs == b"\x01", 5.0, "flood on")
    assert wait_job(machine, job)["outcome"]["outcome"] == "completed"
    assert sim(machine).io_nodes[10].outputs == b"\x00"


def test_m64_and_m65_switch_the_output_at_bit_p_at_their_row(machine):
    controller = machine.controller
    job = controller.submit("o.nc", "G21 G90\nM64 P4\nG01 X20 F600\nM65 P4\nG01 X0\n")["job"]["id"]
    wait_for(lambda: sim(machine).io_nodes[10].outputs == b"\x10", 5.0, "clamp on")
    wait_for(lambda: sim(machine).io_nodes[10].outputs == b"\x00", 10.0, "clamp off at M65's row")
    events = wait_job(machine, job)["outcome"]["machine_events"]
    assert [(e.get("code"), e.get("outputs")) for e in events][:2] == [("M64", {"clamp": True}),
                                                                       ("M65", {"clamp": False})]
    assert events[1]["row"] > 100  # after the first move (G01 X20 at 10 mm/s: ~2 s)


def test_abort_quick_stops_and_disables_the_spindle_and_the_next_job_enables_it(machine):
    controller = machine.controller
    job = controller.submit("a.nc", "G21 G90\nS3000 M4\nG01 X50 F600\nM5\n")["job"]["id"]
    wait_for(lambda: spindle_rpm(machine) < -2900 and controller.status()["job"]["cycle"] > 10, 10.0, "M4 running")
    controller.abort()
    outcome = wait_job(machine, job)["outcome"]
    assert outcome["outcome"] == "aborted"
    wait_for(lambda: controller.status()["spindle"]["drive_state"] == "SWITCH ON DISABLED", 5.0, "spindle disabled")
    assert spindle_rpm(machine) == 0
    controller.reset()
    job = controller.submit("b.nc", "G21 G90\nS1000 M3\nG01 X1 F600\n")["job"]["id"]
    assert wait_job(machine, job)["outcome"]["outcome"] == "completed"
    wait_for(lambda: spindle_rpm(machine) == 0, 5.0, "spindle ramped to rest at job end")


def test_an_unreachable_speed_stops_the_job_with_one_line(machine):
    controller = machine.controller
    # The drive's own profile acceleration 0x6083 set to 100 counts/s² (minutes to 6000 rpm), in
    # its dictionary as a drive's parameter: the master wrote it at bring-up, and the drive
    # applies it with the next SDO write from the bus (M3's 0x60FF). (Overwriting the drive's
    # cached parameters after a sleep raced with that write on a loaded host.)
    sim(machine)[5].node.sdo[0x6083].raw = 100
    job = controller.submit("slow.nc", "G21 G90\nS6000 M3\nG01 X5 F600\n")["job"]["id"]
    outcome = wait_job(machine, job)["outcome"]
    assert outcome["outcome"] == "fault"
    assert outcome["reason"].startswith("slow.nc:2: M3: the spindle did not reach 6000 rpm within 3 s")
    assert outcome["sent"] == 0 or abs(outcome["final_position"]["X"]["commanded_mm"]) < 1e-9


def test_estop_aborts_the_job_disables_everything_and_refuses_motion_until_released(machine):
    controller = machine.controller
    job = controller.submit("e.nc", "G21 G90\nS3000 M3\nM8\nG01 X50 F600\n")["job"]["id"]
    wait_for(lambda: controller.status()["job"]["cycle"] > 20, 10.0, "moving")
    sim(machine).set_io_input("estop", True)
    outcome = wait_job(machine, job)["outcome"]
    assert outcome["outcome"] == "fault" and outcome["reason"].startswith("e-stop input estop (io node 10 bit 0")
    wait_for(lambda: controller.status()["phase"] == "disabled", 5.0, "axes disabled")
    wait_for(lambda: controller.status()["spindle"]["drive_state"] == "SWITCH ON DISABLED", 5.0, "spindle disabled")
    assert sim(machine).io_nodes[10].outputs == b"\x00"
    with pytest.raises(InputError, match="e-stop input estop .* is active: release it first"):
        controller.submit("again.nc", "G21 G90\nG01 X1 F600\n")
    with pytest.raises(InputError, match="e-stop"):
        controller.reset()
    sim(machine).set_io_input("estop", False)
    wait_for(lambda: controller.status()["io"]["estop_active"] is False, 5.0, "estop released")
    controller.reset()
    job = controller.submit("again.nc", "G21 G90\nG01 X1 F600\n")["job"]["id"]
    assert wait_job(machine, job)["outcome"]["outcome"] == "completed"


def test_a_limit_input_faults_the_job_with_one_line_naming_the_axis(machine):
    controller = machine.controller
    job = controller.submit("l.nc", "G21 G90\nG01 X50 F600\n")["job"]["id"]
    wait_for(lambda: controller.status()["job"]["cycle"] > 20, 10.0, "moving")
    sim(machine).set_io_input("limit_x_max", True)
    outcome = wait_job(machine, job)["outcome"]
    assert outcome["outcome"] == "fault"
    assert outcome["reason"] == "limit input limit_x_max (io node 10 bit 1) is active: axis X"
    assert [e["event"] for e in outcome["machine_events"]] == ["job_machine_fault", "devices_off"]
    with pytest.raises(InputError, match="limit input limit_x_max .* axis X is on its limit switch"):
        controller.submit("again.nc", "G21 G90\nG01 X1 F600\n")


def test_m5_and_m9_after_the_last_move_are_done_and_recorded_before_the_job_end(machine):
    # the usual end of a CAM program; their row is only reached once playback is over
    controller = machine.controller
    job = controller.submit("end.nc", "G21 G90\nS3000 M3\nM8\nG01 X5 F1200\nM5 M9\nM30\n")["job"]["id"]
    outcome = wait_job(machine, job)["outcome"]
    assert outcome["outcome"] == "completed", outcome["reason"]
    events = [(e["event"], e.get("code")) for e in outcome["machine_events"]]
    assert events[-3:] == [("spindle_event", "M5"), ("coolant_event", "M9"), ("devices_off", None)]
    m9 = outcome["machine_events"][-2]
    assert m9["at"] == "end.nc:5" and m9["outputs"]["coolant_flood"] is False


def test_an_mdi_of_spindle_and_output_words_runs_them_without_motion_and_leaves_them_on(machine):
    controller = machine.controller
    before = [a["commanded_mm"] for a in controller.status()["axes"]]
    job = controller.mdi("M3 S1000")["job"]["id"]
    outcome = wait_job(machine, job)["outcome"]
    assert outcome["outcome"] == "completed", outcome["reason"]
    assert [(e.get("code"), e.get("rpm"), e.get("at_speed")) for e in outcome["machine_events"]][0] == \
        ("M3", 1000.0, True)
    assert outcome["machine_events"][-1]["event"] == "devices_kept"
    assert abs(spindle_rpm(machine) - 1000.0) < 20.0  # still turning after the job
    status = controller.status()
    assert status["spindle"]["commanded_rpm"] == pytest.approx(1000.0, abs=0.01) and status["state"] == "idle"
    assert [a["commanded_mm"] for a in status["axes"]] == before  # no axis moved
    assert controller.jobs()["jobs"][0]["id"] == job  # recorded like any job

    job = controller.mdi("S2000")["job"]["id"]  # S alone changes the running spindle (LinuxCNC)
    outcome = wait_job(machine, job)["outcome"]
    assert [(e.get("code"), e.get("rpm"), e.get("at_speed")) for e in outcome["machine_events"]][0] == \
        ("S2000", 2000.0, True)
    assert abs(spindle_rpm(machine) - 2000.0) < 40.0
    assert controller.status()["spindle"]["commanded_rpm"] == pytest.approx(2000.0, abs=0.01)

    job = controller.mdi("M8\nM64 P4")["job"]["id"]
    assert wait_job(machine, job)["outcome"]["outcome"] == "completed"
    assert sim(machine).io_nodes[10].outputs == b"\x11"  # flood and clamp stay on
    wait_for(lambda: controller.status()["coolant"] == {"mist": False, "flood": True}, 5.0, "status: flood on")
    job = controller.mdi("M5 M9")["job"]["id"]
    outcome = wait_job(machine, job)["outcome"]
    assert [e.get("code") for e in outcome["machine_events"]][:2] == ["M5", "M9"]
    wait_for(lambda: spindle_rpm(machine) == 0, 5.0, "spindle at rest after mdi M5")
    assert sim(machine).io_nodes[10].outputs == b"\x10"  # coolant off, the clamp (M64) kept
    wait_for(lambda: controller.status()["coolant"] == {"mist": False, "flood": False}, 5.0, "status: coolant off")
    job = controller.mdi("S500")["job"]["id"]  # the spindle stopped: S alone starts nothing
    assert wait_job(machine, job)["outcome"]["outcome"] == "completed"
    assert controller.status()["spindle"]["commanded_rpm"] == 0.0 and spindle_rpm(machine) == 0

    with pytest.raises(InputError, match="^only.nc: the program has no motion$"):
        controller.submit("only.nc", "M3 S1000\n")  # a program file still needs motion


def test_the_cli_mdi_m3_turns_the_spindle_and_m5_stops_it(machine):
    socket = str(machine.config.control.socket)

    def cli(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "nurbsmotion", *args, "--socket", socket], capture_output=True,
                              text=True, env=subprocess_environment(), timeout=60)

    done = cli("mdi", "M3 S1000", "--no-progress")
    assert done.returncode == 0, done.stderr
    assert "completed" in done.stdout and "Traceback" not in done.stderr
    assert abs(spindle_rpm(machine) - 1000.0) < 20.0
    done = cli("mdi", "M5", "--no-progress")
    assert done.returncode == 0, done.stderr
    wait_for(lambda: spindle_rpm(machine) == 0, 5.0, "spindle at rest after mdi M5")


# Long enough that its events lie in later chunks than the first (streamed_job.FIRST_CHUNK_CYCLES
# 200 rows, then CHUNK_CYCLES): each X move of 40 mm at 20 mm/s is ~500 rows at T = 4 ms.
LONG_MILL = ("G21 G90\nS6000 M3\nG01 X40 F1200\nM8\nG01 X0\nS9000\nG01 X40\nM64 P4\nG01 X0\nM65 P4\n"
             "G01 X40\nM5 M9\nM30\n")


def test_a_streamed_job_does_its_events_at_the_rows_the_whole_plan_puts_them(machine):
    """A machine with a spindle and an I/O node streams lookahead jobs from the planner worker
    like any other (until session 8 it planned them whole in the daemon: 20 s and the GIL for a
    long program). Its events get their rows as the chunks arrive; they must be the rows the
    whole plan gives (chunked plans are the whole plan's rows), and the spindle waits hold
    the axes at rest until the spindle is at speed."""
    import numpy as np

    from nurbsmotion.service.job_events import event_rows, with_spindle_waits
    from nurbsmotion.service.planner import plan_job

    controller = machine.controller
    job = controller.submit("long.nc", LONG_MILL)["job"]["id"]
    info = wait_job(machine, job, timeout_s=60.0)
    assert info["outcome"]["outcome"] == "completed", info["outcome"]["reason"]
    assert info["plan"]["streamed"] is True
    done = [(e["code"], e["row"]) for e in info["outcome"]["machine_events"] if "code" in e]
    whole = with_spindle_waits(plan_job("long.nc", LONG_MILL, machine.config, np.zeros(3)))
    expected = [(e.event.code, e.row) for e in event_rows(whole)]
    assert done == expected and max(row for _, row in done) > 1000
    streamed_waits = [(p["row"], p["reason"]) for p in info["plan"]["pauses"]]
    assert streamed_waits == [(p.row, p.reason) for p in whole.pauses] and len(streamed_waits) == 2
    assert all("waiting for the spindle at speed" in reason for _, reason in streamed_waits)
    s9000 = next(e for e in info["outcome"]["machine_events"] if e.get("code") == "S9000")
    assert s9000["at_speed"] is True and s9000["row"] > 200
