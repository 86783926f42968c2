"""Records the master hands out: fault reports and thread-safe status snapshots."""

from __future__ import annotations

from dataclasses import dataclass, field

FAULT_KINDS = ("emcy", "heartbeat", "fault_bit", "following_error", "bus_error", "bringup", "stall")


@dataclass(frozen=True)
class FaultReport:
    """What went wrong, where and when: ``cycle`` is the master's cycle counter (-1 = bring-up)."""

    node_id: int | None
    axis: str | None
    kind: str  # one of FAULT_KINDS
    code: int  # EMCY error code, statusword, following error in counts, heartbeat state...
    cycle: int
    message: str

    def __str__(self) -> str:
        return self.message


@dataclass(frozen=True)
class AxisStatus:
    name: str
    node_id: int
    state: str  # CiA 402 state name from the last statusword
    statusword: int | None
    position_counts: int | None  # 0x6064 from the last valid TPDO1
    setpoint_counts: int  # last set-point sent
    following_error_counts: int | None  # 0x60F4 if mapped, else set-point effective - actual
    bad_tpdo_count: int  # TPDOs of the wrong length (never used as position)
    emcy_count: int
    last_emcy_code: int | None


@dataclass(frozen=True)
class CycleStats:
    """Timing of the cyclic loop: lateness = time the SYNC left after its deadline."""

    cycles: int
    late_cycles: int  # lateness > late_threshold_s
    missed_cycles: int  # lateness > one period: the deadline grid was moved on
    late_threshold_s: float
    lateness_p50_s: float
    lateness_p99_s: float
    lateness_max_s: float
    send_errors: int


@dataclass(frozen=True)
class MasterStatus:
    """Snapshot of the master for the daemon (safe to take from any thread)."""

    phase: str  # 'offline' | 'enabling' | 'holding' | 'streaming' | 'stopping' | 'pausing' | 'held' | 'quick_stop' | 'disabled'
    cycle: int
    axes: tuple[AxisStatus, ...]
    timing: CycleStats
    job_index: int | None  # index of the last set-point sent of the running job
    job_length: int | None
    faults: tuple[FaultReport, ...] = field(default=())
    pause: int | None = None  # phase 'held' at a pause row: its index in the job's pauses (None: a hold request)
    rate: float | None = None  # the running job's playback rate now (1: as planned; 0: at rest, held); None: no job


@dataclass(frozen=True)
class JobResult:
    """How a streamed job ended: 'done' | 'stopped' | 'aborted' | 'faulted'."""

    outcome: str
    sent: int  # planned set-points sent (index of the last + 1); a controlled stop adds interpolated ones
    length: int
    faults: tuple[FaultReport, ...]
    missed_cycles: int
    late_cycles: int
