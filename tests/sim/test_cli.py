"""``nurbsmotion sim``: drives for a configuration, faults from the command line, clean exit."""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import threading
import time
import uuid
from pathlib import Path

import canopen
import pytest

import nurbsmotion
from nurbsmotion.cli import main
from nurbsmotion.cli.sim import parse_faults, serve
from nurbsmotion.runtime import SIM_DRIVES_PRIORITY
from nurbsmotion.config import load_config
from nurbsmotion.sim import SimNetwork, read_csv

from conftest import FrameLog, rpdo, wait_for


def write_config(tmp_path: Path, channel: str) -> Path:
    path = tmp_path / "machine.yaml"
    path.write_text(
        "cycle_period_ms: 2\n"
        f"bus: {{interface: virtual, channel: {channel}}}\n"
        "axes:\n"
        "  - {name: X, node_id: 1, mode: csp}\n"
        "  - {name: Z, node_id: 2, mode: ip, identity: {vendor_id: 0x99, product_code: 0x42}}\n"
    )
    return path


def test_serve_runs_the_configured_drives_with_faults_and_writes_recordings(tmp_path: Path) -> None:
    channel = f"sim-cli-{uuid.uuid4().hex}"
    machine = load_config(write_config(tmp_path, channel))
    faults = parse_faults(["node=2,kind=fault,at_sync=3,code=0x2310"], machine)
    frames = FrameLog()
    master = canopen.Network()
    master.NOTIFIER_CYCLE = 0.05
    master.connect(interface="virtual", channel=channel)
    master.notifier.add_listener(frames)
    stop = threading.Event()
    ready: list[SimNetwork] = []
    server = threading.Thread(target=serve, args=(machine, faults, stop),
                              kwargs={"record_dir": tmp_path / "rec", "on_ready": ready.append})
    server.start()
    try:
        wait_for(lambda: ready, what="drives up")
        net = ready[0]
        z = canopen.RemoteNode(2, str(net[2].eds_path))
        master.add_node(z)
        assert (z.sdo[0x1018][1].raw, z.sdo[0x1018][2].raw) == (0x99, 0x42)
        # out of the box: the EDS defaults, not the configuration's mode and 2 ms cycle
        assert z.sdo[0x6061].raw == 8 and (z.sdo[0x60C2][1].raw, z.sdo[0x60C2][2].raw) == (1, -3)
        assert net[2].period_s == pytest.approx(0.001)
        master.send_message(0x000, bytes([0x01, 0]))
        wait_for(lambda: all(d.nmt_state == 0x05 for d in net.drives.values()), what="operational")
        for word in (0x06, 0x07, 0x0F):
            master.send_message(0x201, rpdo(word, 0))
            master.send_message(0x80, b"")
        master.send_message(0x201, rpdo(0x0F, 77))
        master.send_message(0x80, b"")
        wait_for(lambda: frames.of(0x82), what="EMCY of node 2")
        assert frames.of(0x82)[0][:2] == (0x2310).to_bytes(2, "little")
        wait_for(lambda: len(net[1].recorder) == 2, what="set-points of node 1")
    finally:
        stop.set()
        server.join(timeout=5)
        master.disconnect()
    assert not server.is_alive()
    assert [(r.sync_index, r.setpoint_counts) for r in read_csv(tmp_path / "rec" / "node1.csv")] == [(3, 0), (4, 77)]  # the enabling RPDO carries a set-point too
    assert read_csv(tmp_path / "rec" / "node2.csv") == []


@pytest.mark.parametrize(
    "extra,message",
    [
        (["--fault", "node=2,kind=melt"], "fault spec 'node=2,kind=melt': unknown fault kind"),
        (["--fault", "node=9,kind=fault"], "node 9 is not an axis"),
        (["--fault", "kind=fault"], "node is required"),
        (["--lag-cycles", "-1"], "--lag-cycles: must be >= 0"),
        (["--max-velocity-counts-s", "0"], "--max-velocity-counts-s: must be > 0"),
        (["--missing-setpoint", "guess"], "--missing-setpoint: must be one of hold, extrapolate, got 'guess'"),
        (["--sync-loss-periods", "0.5"], "--sync-loss-periods: must be >= 1, got 0.5"),
        (["--rt-priority", "0"], "--rt-priority: must be 1..99 (SCHED_FIFO), got 0"),
        (["--rt-priority", "100"], "--rt-priority: must be 1..99 (SCHED_FIFO), got 100"),
    ],
)
def test_bad_options_are_one_line_and_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str], message: str) -> None:
    config = write_config(tmp_path, f"sim-cli-{uuid.uuid4().hex}")
    assert main(["sim", "--config", str(config), *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]


def test_sigterm_exits_0_within_a_second_and_writes_the_recordings(tmp_path: Path) -> None:
    config = write_config(tmp_path, f"sim-cli-{uuid.uuid4().hex}")
    env = dict(os.environ, PYTHONPATH=str(Path(nurbsmotion.__file__).parents[1]))
    proc = subprocess.Popen(
        [sys.executable, "-m", "nurbsmotion", "sim", "--config", str(config), "--record-dir", str(tmp_path / "rec"),
         "--missing-setpoint", "extrapolate", "--own-cycle", "--sync-loss-periods", "4"],
        stderr=subprocess.PIPE, env=env,
    )
    try:
        deadline = time.monotonic() + 20
        seen = b""
        while b"sim.ready" not in seen:
            assert time.monotonic() < deadline and proc.poll() is None, f"no sim.ready: {seen!r}"
            if select.select([proc.stderr], [], [], 0.5)[0]:
                seen += os.read(proc.stderr.fileno(), 65536)  # unbuffered: select sees the rest
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=1.0) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert sorted(p.name for p in (tmp_path / "rec").iterdir()) == ["node1.csv", "node1.sync.csv", "node2.csv", "node2.sync.csv"]


def test_an_eds_that_does_not_load_names_the_axis_field(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "m.yaml"
    config.write_text("bus: {interface: virtual, channel: x}\naxes:\n  - {name: X, node_id: 1}\n  - {name: Y, node_id: 2, eds: none.eds}\n")
    assert main(["sim", "--config", str(config)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{config}:4: axes[1].eds (Y, node 2): cannot read none.eds" in err[0]


def test_a_bus_that_does_not_open_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "m.yaml"
    config.write_text("bus: {interface: socketcan, channel: nurbs-no-such-if}\naxes:\n  - {name: X, node_id: 1}\n")
    assert main(["sim", "--config", str(config)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bus: cannot open socketcan channel nurbs-no-such-if" in err[0]


def test_home_sensors_specs_are_parsed_per_axis_node(tmp_path: Path) -> None:
    from nurbsmotion.cli.sim import parse_home_sensors
    from nurbsmotion.errors import InputError
    from nurbsmotion.sim.homing import HomeSensors

    machine = load_config(write_config(tmp_path, "unused"))
    sensors = parse_home_sensors(["node=1,negative_limit=-2500,positive_limit=2500,index_pitch=1000,index_phase=300"],
                                 machine)
    assert sensors == {1: HomeSensors(-2500.0, 2500.0, 1000.0, 300.0)}
    for spec, message in [("node=5,negative_limit=0", "node must be an axis"),
                          ("node=1,negative=0", "unknown key 'negative'"),
                          ("node=1,index_pitch=x", "index_pitch='x' is not a number"),
                          ("node=1,index_pitch=0", "index_pitch must be > 0"),
                          ("node=1,negative_limit=5,positive_limit=5", "must be below positive_limit"),
                          ("node=1,negative_limit", "expected key=value")]:
        with pytest.raises(InputError, match=message):
            parse_home_sensors([spec], machine)
    with pytest.raises(InputError, match="node 1 given twice"):
        parse_home_sensors(["node=1", "node=1"], machine)


def test_a_spindle_spec_adds_a_velocity_drive_at_a_free_node(tmp_path: Path) -> None:
    from nurbsmotion.cli.sim import parse_spindle
    from nurbsmotion.errors import InputError
    from nurbsmotion.sim import SpindleSim

    machine = load_config(write_config(tmp_path, f"sim-cli-{uuid.uuid4().hex}"))
    spindle = parse_spindle("node=5,counts_per_rev=4096", machine)
    assert spindle == SpindleSim(5, 4096.0) and spindle.rpm(4096) == 60.0
    assert parse_spindle(None, machine) is None
    for spec, message in [("node=1,counts_per_rev=4096", "not an axis or io node"),
                          ("node=5", "both required"), ("node=5,counts_per_rev=0", "must be > 0"),
                          ("node=5,rpm=3", "expected node=N,counts_per_rev=C"),
                          ("node=x,counts_per_rev=1", "must be numbers")]:
        with pytest.raises(InputError, match=message):
            parse_spindle(spec, machine)
    net = SimNetwork.for_machine(machine, spindle=spindle)
    assert net.spindle == spindle and net[5].name == "spindle/node5"
    with net:
        assert {3, 9} <= net[5].axis.params.modes


def test_rt_priority_asks_for_it_on_the_drives_threads(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """--rt-priority: the drives' receive and ticker threads ask for SCHED_FIFO N (recorded
    here instead of granted: a real FIFO thread pinned to a CPU shared with other work makes
    a test of timing, not of the option)."""
    asked: list[int | None] = []

    def fake_realtime(priority: int | None, thread_id: int = 0) -> str:
        asked.append(priority)
        return "SCHED_FIFO"

    monkeypatch.setattr("nurbsmotion.sim.network.set_thread_realtime", fake_realtime)
    machine = load_config(write_config(tmp_path, f"sim-cli-{uuid.uuid4().hex}"))
    stop = threading.Event()
    ready: list[SimNetwork] = []
    server = threading.Thread(target=serve, args=(machine, [], stop),
                              kwargs={"on_ready": ready.append, "rt_priority": SIM_DRIVES_PRIORITY})
    server.start()
    try:
        wait_for(lambda: ready, what="drives up")
        net = ready[0]
        wait_for(lambda: set(net.thread_policy) == {"receive", "ticker"}, what="both threads' policy")
        assert net.rt_priority == SIM_DRIVES_PRIORITY and asked == [SIM_DRIVES_PRIORITY] * 2
    finally:
        stop.set()
        server.join(timeout=5)
    assert not server.is_alive()
