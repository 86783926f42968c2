"""The kernel queue's lease (fieldbus.bcm_queue), without a bus: what each TX_SETUP asks
the kernel to send. One lap of the ring while the queued cycles differ; REST_LEASE_S while
every slot carries the same frames (sending the ring round again changes nothing)."""

from __future__ import annotations

import struct

from nurbsmotion.fieldbus.bcm_queue import REST_LEASE_S, BcmQueueWriter
from nurbsmotion.fieldbus.cyclic_velocity import CyclicVelocity
from nurbsmotion.fieldbus.supervisor import CycleHistory
from nurbsmotion.fieldbus.writer import CyclicFrames

PERIOD_S = 0.004
N_AXES = 3


def pack(data: bytearray, controlword: int, setpoint: int) -> None:
    struct.pack_into("<Hi", data, 0, controlword, setpoint)


class FakeBcmSocket:
    """Keeps the count (frames the kernel may still send) of each TX_SETUP."""

    def __init__(self) -> None:
        self.counts: list[int] = []

    def sendmsg(self, parts: list[bytes]) -> None:
        head = parts[0]
        self.counts.append(struct.unpack_from("@III", head, 0)[2])  # opcode, flags, count (bcm_msg_head)


class FakeEcho:
    """SYNCs 'sent by the kernel' between the cycle thread's count and its next read."""

    def __init__(self) -> None:
        self.pending = 0
        self.drains = 0

    def drain(self, on_sync) -> None:
        self.drains += 1
        for _ in range(self.pending):
            on_sync(0.0)
        self.pending = 0


def writer(frames: CyclicFrames | None = None) -> tuple[BcmQueueWriter, CycleHistory, FakeBcmSocket]:
    frames = frames or CyclicFrames([(0x200 + n, 6, n, pack) for n in range(N_AXES)])
    history = CycleHistory(4096, N_AXES)
    queue = BcmQueueWriter("vcan-test", frames, history, PERIOD_S, 0.5 * PERIOD_S, bus=None)  # type: ignore[arg-type]
    fake = FakeBcmSocket()
    queue.bcm_sock = fake  # type: ignore[assignment]
    queue.echo = FakeEcho()  # type: ignore[assignment]
    return queue, history, fake


def hold_tail(controlword: int, setpoint: list[int]) -> object:
    def tail(sp: list[list[int]], cw: list[list[int]]) -> int:
        for row in range(len(sp)):
            sp[row][:] = setpoint
            cw[row][:] = [controlword] * N_AXES
        return 0
    return tail


def test_at_rest_the_lease_covers_rest_lease_s_and_a_job_cuts_it_back_to_the_ring() -> None:
    queue, history, fake = writer()
    hold = [100, 200, 300]
    for k in range(history.size):
        history.store(k, [0x0F] * N_AXES, hold)
    queue.commit(0, queue.horizon(0, 0, moving=False), 1, hold_tail(0x0F, hold))
    # the first TX_SETUP: the slot of cycle 64 (ring slot 63) is not written yet (it would be
    # sent only in the second lap): one lap
    assert not queue.ring_uniform()
    assert queue.lease_end == queue.cycles - 1 - queue.pad
    queue.c = 1
    queue.commit(1, queue.horizon(1, 0, moving=False), 2, hold_tail(0x0F, hold))
    assert queue.ring_uniform()
    rest_cycles = round(REST_LEASE_S / PERIOD_S)
    assert queue.lease_end == 1 + rest_cycles - 1 - queue.pad
    assert fake.counts[-1] == (queue.lease_end - 1) * queue.frames.per_cycle
    # a job: the next cycles move; the same renewal brings the lease back within one lap
    for k in range(12, 20):
        history.store(k, [0x0F] * N_AXES, [h + k for h in hold])
    queue.c = 10
    queue.commit(10, 19, 12, hold_tail(0x0F, [h + 19 for h in hold]))
    assert not queue.ring_uniform()
    assert queue.lease_end == 10 + queue.cycles - 1 - queue.pad
    assert fake.counts[-1] == (queue.lease_end - 10) * queue.frames.per_cycle
    assert queue.lease_end - 10 < queue.cycles  # never a second lap of frames that differ


def test_a_controlword_change_alone_is_not_uniform() -> None:
    queue, history, _ = writer()
    for k in range(history.size):
        history.store(k, [0x07] * N_AXES, [0, 0, 0])
    queue.commit(0, queue.horizon(0, 0, moving=False), 1, hold_tail(0x0F, [0, 0, 0]))  # enabling: 0x07 then 0x0F
    assert not queue.ring_uniform()
    assert queue.lease_end == queue.cycles - 1 - queue.pad


def test_a_cycle_slot_frame_is_packed_with_its_cycle_in_every_ring_slot() -> None:
    """The csv spindle's 0x60FF (fieldbus.cyclic_velocity) rides after the axes' RPDOs: each
    queued cycle x carries pack(x), whether it was computed or is the tail."""
    from nurbsmotion.fieldbus.bcm_queue import FRAME_BYTES

    frames = CyclicFrames([(0x200 + n, 6, n, pack) for n in range(N_AXES)],
                          [(0x205, 4, lambda data, x: struct.pack_into("<i", data, 0, 1000 * x))])
    history = CycleHistory(4096, N_AXES)
    queue = BcmQueueWriter("vcan-test", frames, history, PERIOD_S, 0.5 * PERIOD_S, bus=None)  # type: ignore[arg-type]
    queue.bcm_sock = FakeBcmSocket()  # type: ignore[assignment]
    assert queue.fpc == 1 + N_AXES + 1
    for k in range(history.size):
        history.store(k, [0x0F] * N_AXES, [0, 0, 0])
    queue.commit(0, queue.horizon(0, 0, moving=False), 1, hold_tail(0x0F, [0, 0, 0]))
    slot_bytes = queue.fpc * FRAME_BYTES
    for x in range(queue.op_base, queue.op_base + queue.cycles - 1):
        frame = ((x - queue.op_base) % queue.cycles) * slot_bytes + (1 + N_AXES) * FRAME_BYTES
        can_id, dlc = struct.unpack_from("<IB", queue.buf, frame)
        assert (can_id, dlc) == (0x205, 4)
        assert struct.unpack_from("<i", queue.buf, frame + 8)[0] == 1000 * x


def running_queue_at(c: int, frames: CyclicFrames | None = None) -> tuple[BcmQueueWriter, CycleHistory, FakeEcho]:
    queue, history, _ = writer(frames)
    echo = queue.echo
    assert isinstance(echo, FakeEcho)
    hold = [100, 200, 300]
    for k in range(history.size):
        history.store(k, [0x0F] * N_AXES, hold)
    queue.commit(0, queue.horizon(0, 0, moving=True), 1, hold_tail(0x0F, hold))
    echo.pending = c  # the wire reaches cycle c
    echo.drain(queue._on_sync)
    return queue, history, echo


def test_a_change_the_wire_overtook_is_counted_and_widens_the_change_guard() -> None:
    queue, history, echo = running_queue_at(10)
    assert queue.c == 10 and queue.change_guard == 3
    first = queue.c + queue.change_guard + 1  # a stop from cycle 14 on, as the master asks
    echo.pending = 6  # the cycle thread was held up: the wire reached 16 before the write landed
    queue.commit(10, queue.h, first, hold_tail(0x0F, [0, 0, 0]))
    assert queue.c == 16
    assert queue.overtaken == 3  # cycles 14, 15, 16 may have left with their old frames
    assert queue.change_guard == 6 and queue.guard == 3  # the horizon's guard stays


def test_a_change_beyond_the_wire_keeps_the_guard() -> None:
    queue, history, echo = running_queue_at(10)
    echo.pending = 2  # the wire moved to 12: still before the first changed cycle (14)
    queue.commit(10, queue.h, 14, hold_tail(0x0F, [0, 0, 0]))
    assert queue.overtaken == 0 and queue.change_guard == 3


def test_only_changes_of_queued_cycles_read_the_echo_again() -> None:
    queue, history, echo = running_queue_at(10)
    drains = echo.drains
    queue.commit(10, queue.h + 8, queue.h + 1, hold_tail(0x0F, [0, 0, 0]))  # new cycles only
    assert echo.drains == drains


def test_the_change_guard_never_grows_beyond_its_bound() -> None:
    from nurbsmotion.fieldbus.bcm_queue import MAX_GUARD_CYCLES
    queue, history, echo = running_queue_at(10)
    echo.pending = 40
    queue.commit(10, queue.h, 14, hold_tail(0x0F, [0, 0, 0]))
    assert queue.change_guard == MAX_GUARD_CYCLES


def queued_velocity(queue: BcmQueueWriter, ring: bytes, x: int) -> int:
    """The csv 0x60FF (the one extra, after the axes' RPDOs) that ``ring`` holds for cycle x."""
    from nurbsmotion.fieldbus.bcm_queue import FRAME_BYTES
    slot = ((x - queue.op_base) % queue.cycles) * queue.fpc * FRAME_BYTES
    return struct.unpack_from("<i", ring, slot + (1 + N_AXES) * FRAME_BYTES + 8)[0]


def velocity_queue_at(c: int, step_counts_s: float) -> tuple[CyclicVelocity, BcmQueueWriter, FakeEcho]:
    """A running queue at wire cycle c whose one extra is a csv 0x60FF (CyclicVelocity)."""
    velocity = CyclicVelocity(5, 0x205, step_counts_s)
    frames = CyclicFrames([(0x200 + n, 6, n, pack) for n in range(N_AXES)],
                          [(velocity.cob_id, velocity.dlc, velocity.pack)], [velocity])
    queue, _, echo = running_queue_at(c, frames)
    return velocity, queue, echo


def test_a_velocity_ramp_the_wire_overtook_starts_beyond_the_wire_without_a_step() -> None:
    """The cycle thread asks for a new 0x60FF from cycle 14 (wire 10 + change guard 3 + 1) and
    is held up until the wire reaches 16 before its TX_SETUP: cycles up to 16 have left with
    the old value (0). Before the fix the queue then sent cycle 17 as the ramp's 3rd step (a
    jump of 3 steps after 0, the vcan lane's 'a jump in 0x60FF'); now the ramp starts after
    wire + guard and the wire sees one step per cycle at most."""
    step = 100.0
    velocity, queue, echo = velocity_queue_at(10, step)
    before = bytes(queue.buf)
    velocity.request(1000.0)
    assert velocity.apply(14)  # as the cycle loop: from c + change_guard + 1
    echo.pending = 6  # the wire reaches 16 between the count and the write
    queue.commit(10, queue.h, 14, hold_tail(0x0F, [100, 200, 300]))
    assert queue.c == 16
    on_wire = [queued_velocity(queue, before, x) for x in range(11, 17)] + \
        [queued_velocity(queue, bytes(queue.buf), x) for x in range(17, queue.lease_end + 1)]
    assert max(abs(b - a) for a, b in zip(on_wire, on_wire[1:])) <= step
    first_free = 16 + queue.guard + 1
    assert [velocity.value_at(x) for x in (first_free - 1, first_free, first_free + 1)] == [0, 0, 100]
    assert on_wire[-1] == 1000  # the ramp still reaches the target


def test_a_velocity_change_ahead_of_the_wire_is_not_moved() -> None:
    velocity, queue, echo = velocity_queue_at(10, 100.0)
    velocity.request(1000.0)
    velocity.apply(14)
    echo.pending = 2  # wire 12: cycle 14 is still beyond wire + guard - 1
    queue.commit(10, queue.h, 14, hold_tail(0x0F, [100, 200, 300]))
    assert [velocity.value_at(x) for x in (14, 15)] == [0, 100]
    assert queued_velocity(queue, bytes(queue.buf), 15) == 100


def test_a_velocity_ramp_queued_by_an_earlier_write_is_not_moved_by_a_later_change() -> None:
    """A ramp from 15 went out in the TX_SETUP of wake-up 10; at wake-up 11 a stop of the axes
    rewinds to 15 and the cycle thread is held up until the wire reaches 16: the wire may have
    sent the ramp's first step already (16: 100), so the ramp stays where it is (moving it to
    20 would send 0 after 100) and the check after the write counts the axes' cycles."""
    velocity, queue, echo = velocity_queue_at(10, 100.0)
    velocity.request(1000.0)
    velocity.apply(15)
    queue.commit(10, queue.h, 15, hold_tail(0x0F, [100, 200, 300]))  # the wire still at 10: queued as is
    echo.pending = 1
    echo.drain(queue._on_sync)  # wake-up 11
    echo.pending = 5  # the wire reaches 16 before the next write
    queue.commit(11, queue.h, 15, hold_tail(0x0F, [0, 0, 0]))
    assert [queued_velocity(queue, bytes(queue.buf), x) for x in (15, 16, 17, 18)] == [0, 100, 200, 300]
    assert queue.overtaken == 2  # 15 and 16 (the axes' rows) may have left old
