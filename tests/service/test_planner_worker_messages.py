"""The checked program crosses from the planner worker to the daemon as its store entry's path
(the daemon maps the entry), or without a store in slices (service.planner_worker.send_program
/ receive_program): one pickle of a long program held the daemon's interpreter lock for seconds."""

from __future__ import annotations

import mmap
import multiprocessing
import pickle
import threading

import numpy as np
import pytest

from nurbsmotion.program import ReadOptions
from nurbsmotion.program.gcode import parse_gcode
from nurbsmotion.service import planner_worker
from nurbsmotion.errors import InputError
from nurbsmotion.service.planner_worker import (CheckedProgram, EntryGone, PlanRequest, ProgramBlocks, read_or_load,
                                                receive_program, send_program, store_checked)
from tests.helpers import memory_of


def zigzag(lines: int) -> str:
    return "G21 G90 F3000\n" + "".join(f"G01 X{i % 2} Y{i * 0.001:.3f}\n" for i in range(1, lines + 1)) + "M30\n"


def test_a_long_program_arrives_whole_in_slices_none_longer_than_the_limit(monkeypatch):
    monkeypatch.setattr(planner_worker, "BLOCKS_PER_MESSAGE", 100)
    program = parse_gcode(zigzag(1050), "z.nc", np.zeros(3))
    daemon_end, worker_end = multiprocessing.Pipe(duplex=False)
    sent: list[object] = []

    class Recording:
        def send(self, message: object) -> None:
            sent.append(message)
            worker_end.send(message)

    sender = threading.Thread(target=send_program, args=(Recording(), program))  # the pipe holds 64 KiB
    sender.start()
    received = receive_program(daemon_end, daemon_end.recv(), timeout_s=5.0)
    sender.join(5.0)
    assert isinstance(sent[0], CheckedProgram) and sent[0].block_count == 1050 and sent[0].program.blocks == ()
    assert [len(m.blocks) for m in sent[1:] if isinstance(m, ProgramBlocks)] == [100] * 10 + [50]
    assert [b.source.line for b in received.blocks] == [b.source.line for b in program.blocks]
    assert np.array_equal(received.end_position, program.end_position)
    assert received.events == program.events and received.name == program.name


def test_a_missing_slice_is_a_timeout_not_a_hang():
    program = parse_gcode(zigzag(3), "z.nc", np.zeros(3))
    daemon_end, worker_end = multiprocessing.Pipe(duplex=False)
    worker_end.send(CheckedProgram(program, 5))  # says five blocks, sends none
    with pytest.raises(TimeoutError, match="after 0 of 5"):
        receive_program(daemon_end, daemon_end.recv(), timeout_s=0.05)


def test_a_slice_is_far_smaller_than_the_whole_program():
    program = parse_gcode(zigzag(5000), "z.nc", np.zeros(3))
    whole = len(pickle.dumps(program))
    one_slice = len(pickle.dumps(ProgramBlocks(program.blocks[:planner_worker.BLOCKS_PER_MESSAGE])))
    assert one_slice * 4 < whole


def test_with_a_store_entry_only_the_outline_crosses_and_the_daemon_maps_the_entry(tmp_path):
    """Issue 25 item 4: no block is pickled through the pipe; the daemon maps the entry the
    worker wrote, as the worker plans from it."""
    program = parse_gcode(zigzag(1050), "z.nc", np.zeros(3))
    request = PlanRequest(None, "z.nc", "", np.zeros(3), ReadOptions(), [0, 1, 2], 100, 10,  # type: ignore[arg-type]
                          tmp_path / "k.checked", "k")
    stored = store_checked(request, program)
    assert stored is not None and isinstance(memory_of(stored.blocks.starts), mmap.mmap)
    sent: list[object] = []
    send_program(type("Pipe", (), {"send": lambda self, m: sent.append(m)})(), stored, False, request.checked_path)
    assert len(sent) == 1 and isinstance(sent[0], CheckedProgram) and sent[0].entry == request.checked_path
    assert len(pickle.dumps(sent[0])) < 10_000  # the outline only
    received = receive_program(None, sent[0], timeout_s=0.0, key="k")
    assert isinstance(memory_of(received.blocks.lines), mmap.mmap) and received.blocks == program.blocks
    (tmp_path / "k.checked").write_bytes(b"")  # gone or damaged between the worker and the daemon: one line
    with pytest.raises(EntryGone, match="k.checked cannot be read"):
        receive_program(None, sent[0], timeout_s=0.0, key="k")


def test_a_withheld_text_is_asked_for_only_when_the_entry_cannot_be_loaded(tmp_path, monkeypatch):
    monkeypatch.setattr(planner_worker, "read_and_check", lambda r: parse_gcode(r.text, r.name, r.start_xyz))  # no machine
    program = parse_gcode(zigzag(20), "z.nc", np.zeros(3))
    request = PlanRequest(None, "z.nc", None, np.zeros(3), ReadOptions(), [0, 1, 2], 100, 10,  # type: ignore[arg-type]
                          tmp_path / "k.checked", "k")
    asked: list[str] = []

    def text_of() -> str:
        asked.append("text")
        return zigzag(20)

    store_checked(request, program)
    assert read_or_load(request, text_of)[1] is True and asked == []
    request.checked_path.write_bytes(b"damaged")
    again, from_store = read_or_load(request, text_of)
    assert not from_store and asked == ["text"] and again.blocks == program.blocks
    with pytest.raises(InputError, match="^z.nc: the program's text was not sent and its checked entry cannot be read$"):
        read_or_load(request)


@pytest.mark.parametrize("blocks", [0, 1, 3, 65535, 65536, 200_001])
def test_path_lengths_keep_at_most_length_points_and_interpolate_between_them(blocks):
    """PathLengths: the running length exact at every stride-th block and at the end, within
    one stride's blocks between (the daemon's progress; 10^6 blocks: 0.5 MB, not 8 MB)."""
    from nurbsmotion.service.planner_worker import LENGTH_POINTS, PathLengths

    lengths = np.random.default_rng(blocks).uniform(0.0, 2.0, blocks)
    exact = np.concatenate([[0.0], np.cumsum(lengths)])
    path = PathLengths.of(lengths)
    assert len(path.before_mm) <= LENGTH_POINTS + 1 and path.total_mm == pytest.approx(exact[-1], rel=1e-12)
    assert (path.stride == 1) == (blocks + 1 <= LENGTH_POINTS)
    for block in sorted({0, 1, blocks // 3, blocks - 1, blocks} & set(range(blocks + 1))):
        k = block // path.stride
        window = exact[min(k * path.stride, blocks):min((k + 1) * path.stride, blocks) + 1]
        assert window[0] - 1e-9 <= path.before(block) <= window[-1] + 1e-9
        if block % path.stride == 0 or block == blocks:
            assert path.before(block) == pytest.approx(exact[block], rel=1e-12, abs=1e-12)
