"""Every real vendor EDS/DCF in tests/data/eds (SOURCES.md): planned and, where it offers the
mode, brought up and run through a short program against a simulated drive built from the
same file; otherwise refused before the bus with the one line naming why."""

from __future__ import annotations

import contextlib
import uuid
from pathlib import Path

import can
import numpy as np
import pytest

from nurbsmotion.config import parse_config
from nurbsmotion.errors import InputError
from nurbsmotion.fieldbus import Master
from nurbsmotion.fieldbus.bringup_plan import plan_drive
from tests.helpers import wait_for

EDS_DIR = Path(__file__).resolve().parents[1] / "data" / "eds"

# (file, mode) -> None: the drive runs it; else a fragment of the one-line refusal
EXPECTED: dict[tuple[str, str], str | None] = {
    ("elmo_Elmo.eds", "ip"): None,
    ("elmo_Elmo.eds", "csp"): None,
    ("elmo_Whistle_Gold_V002.dcf", "ip"): None,
    ("elmo_Whistle_Gold_V002.dcf", "csp"): None,
    ("faulhaber_605.3150.73-A-EK-2-60.eds", "ip"): "has no 0x60C1:01",
    ("faulhaber_605.3150.73-A-EK-2-60.eds", "csp"): "does not allow 0x607A:00 (Target Position) in a PDO",
    ("maxon_epos2_347717.eds", "ip"): "has no 0x60C1:01",
    ("maxon_epos2_347717.eds", "csp"): None,
    ("maxon_epos4_50_15_node1.dcf", "ip"): "has no 0x60C1:01",
    ("maxon_epos4_50_15_node1.dcf", "csp"): None,
    ("nanotec_C5-E-2-09.eds", "ip"): None,
    ("nanotec_C5-E-2-09.eds", "csp"): None,
    ("nanotec_CL3-E-2-0F.eds", "ip"): None,
    ("nanotec_CL3-E-2-0F.eds", "csp"): None,
    ("pilz_prbt.eds", "ip"): None,
    ("pilz_prbt.eds", "csp"): "0x6502 (supported drive modes) = 0x00000043 lacks bit 7",
    ("schunk_PRL120.eds", "ip"): None,
    ("schunk_PRL120.eds", "csp"): "does not allow 0x607A:00 (target_position) in a PDO",
    ("technosoft_ISD860.eds", "ip"): None,  # period in 0x1006; controlword and set-point in two RPDOs
    ("technosoft_ISD860.eds", "csp"): "lacks bit 7",
    ("technosoft_iPOS.eds", "ip"): None,
    ("technosoft_iPOS.eds", "csp"): "lacks bit 7",
    ("zeroerr_eDriver_V1.5.eds", "ip"): "has 0x60C1:01 (Parameter1 of ip function) as int16",
    ("zeroerr_eDriver_V1.5.eds", "csp"): None,
}
MODE_WORDS = {"ip": "interpolated position (mode 7)", "csp": "cyclic synchronous position (mode 8)"}


def machine(eds: str, mode: str, channel: str = "unused"):
    text = (f"cycle_period_ms: 4\nbus: {{interface: virtual, channel: {channel}}}\n"
            f"monitoring: {{heartbeat_producer_ms: 50, heartbeat_consumer_ms: 600}}\n"
            f"axes:\n  - {{name: X, node_id: 1, mode: {mode}, eds: {EDS_DIR / eds}}}\n")
    return parse_config(text, "corpus.yaml")


def test_every_corpus_file_has_an_expectation_for_both_modes():
    files = sorted(p.name for p in EDS_DIR.iterdir() if p.suffix.lower() in (".eds", ".dcf"))
    assert sorted({f for f, _ in EXPECTED}) == files


@pytest.mark.parametrize("eds, mode", sorted(EXPECTED), ids=lambda v: v)
def test_plan_or_one_line_refusal(eds, mode):
    config = machine(eds, mode)
    refusal = EXPECTED[(eds, mode)]
    if refusal is None:
        plan = plan_drive(config, 0, 1000, True)
        assert plan.layout.rpdos and plan.layout.tpdos
        return
    with pytest.raises(InputError) as info:
        Master(config)  # refused before any bus is opened
    text = str(info.value)
    assert "\n" not in text
    assert text.startswith(f"corpus.yaml:5: axes[0].mode (X, node 1): {eds}")
    assert refusal in text and f"so {MODE_WORDS[mode]} is not possible; it offers " in text


RUNNABLE = sorted(k for k, v in EXPECTED.items() if v is None)


def started_sim(sim_package, config):
    """The simulated drive built from the axis' EDS and started (every corpus file builds one:
    a file that stops building is a regression of the simulator, not a skip)."""
    sim = None
    try:
        sim = sim_package.SimNetwork.for_machine(config)
        sim.start()
    except Exception as err:  # noqa: BLE001 - the sim raises many kinds for an EDS it cannot model
        if sim is not None:
            with contextlib.suppress(Exception):
                sim.stop()
        pytest.fail(f"the simulated drive cannot be built from this EDS: {type(err).__name__}: {err}")
    return sim


def applied_exactly(recorded: np.ndarray, planned: np.ndarray) -> bool:
    """The drive's recording (SYNC index, ..., set-point) holds the planned column once, as
    one run at consecutive SYNCs: nothing lost, repeated or altered."""
    for start in np.flatnonzero(recorded[:, 2] == planned[0]):
        run = recorded[start:start + len(planned)]
        if len(run) == len(planned) and np.array_equal(run[:, 2], planned) and np.all(np.diff(run[:, 0]) == 1):
            return True
    return False


@pytest.mark.parametrize("eds, mode", RUNNABLE)
def test_runnable_drive_is_brought_up_and_runs_a_short_program(eds, mode):
    sim_package = pytest.importorskip("nurbsmotion.sim")
    channel = "corpus-" + uuid.uuid4().hex
    config = machine(eds, mode, channel)
    sim = started_sim(sim_package, config)
    bus = can.Bus(interface="virtual", channel=channel)
    master = Master(config, bus, bootup_timeout_s=1.0)
    try:
        master.bring_up()
        k = np.arange(150)
        counts = np.round(2000 * np.sin(2 * np.pi * k / 150)).astype(np.int32).reshape(-1, 1)
        result = master.stream(counts).wait(30.0)
        assert result is not None and result.outcome == "done", result
        # the drive applies an RPDO at the SYNC after it (CiA 301): the last rows land a cycle or two later
        wait_for(lambda: applied_exactly(sim[1].recorder.as_array(), counts[:, 0]), 5.0,
                 "the drive applied every row", 0.02)
        assert applied_exactly(sim[1].recorder.as_array(), counts[:, 0])
    finally:
        master.shutdown()
        bus.shutdown()
        sim.stop()


def test_a_drive_that_cannot_watch_the_master_is_named_at_bring_up(caplog):
    """The Technosoft iPOS has no 0x1016: if the daemon dies, it keeps its last set-point
    (the CiA 301 consumer is the drive's only way to notice): one warning names it."""
    channel = "corpus-" + uuid.uuid4().hex
    config = machine("technosoft_iPOS.eds", "ip", channel)
    sim = started_sim(pytest.importorskip("nurbsmotion.sim"), config)
    bus = can.Bus(interface="virtual", channel=channel)
    master = Master(config, bus, bootup_timeout_s=1.0)
    try:
        with caplog.at_level("WARNING", logger="nurbsmotion.fieldbus.master"):
            master.bring_up()
    finally:
        master.shutdown()
        bus.shutdown()
        sim.stop()
    lines = [r.getMessage() for r in caplog.records if "master_heartbeat_unwatched" in r.getMessage()]
    assert len(lines) == 1 and "node=1 axis=X" in lines[0] and "does not notice a dead master" in lines[0], lines
