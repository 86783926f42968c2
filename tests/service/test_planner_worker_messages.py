"""The checked program crosses from the planner worker to the daemon in slices
(service.planner_worker.send_program / receive_program): one pickle of a long program held
the daemon's interpreter lock for seconds."""

from __future__ import annotations

import multiprocessing
import pickle
import threading

import numpy as np
import pytest

from nurbsmotion.program.gcode import parse_gcode
from nurbsmotion.service import planner_worker
from nurbsmotion.service.planner_worker import CheckedProgram, ProgramBlocks, receive_program, send_program


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
