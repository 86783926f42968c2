"""A master in its own process streaming one strictly increasing job with the kernel queue,
so a test can freeze it (SIGSTOP) while an independent listener watches the wire.

    python -m tests.vcan.queue_master CONFIG CYCLES

Prints 'held <counts...>' after bring-up, 'streaming' once the job is queued and
'result <outcome> <sent> <length> <fault kinds>' at the end; exit code 0 when done.
"""

from __future__ import annotations

import logging
import sys

from nurbsmotion.config import load_config
from nurbsmotion.fieldbus import Master
from nurbsmotion.runtime import CYCLE_THREAD_PRIORITY
from tests.vcan.two_processes import SLOW_KERNEL_MASTER_OPTIONS, strictly_increasing_job


def main(config_path: str, cycles: int) -> int:
    logging.basicConfig(level=logging.WARNING, stream=sys.stderr, format="%(message)s")
    # as the daemon runs it (service.link): SCHED_FIFO cycle thread where allowed (root in UML)
    with Master(load_config(config_path), sync_source="kernel", rt_priority=CYCLE_THREAD_PRIORITY, gc_mode="freeze",
                **SLOW_KERNEL_MASTER_OPTIONS) as master:
        master.bring_up()
        held = [axis.position_counts for axis in master.status().axes]
        print("held", *held, flush=True)
        job = master.stream(strictly_increasing_job(held, cycles))
        print("streaming", flush=True)
        result = job.wait(120.0)
    if result is None:
        print("result none 0 0 -", flush=True)
        return 1
    for fault in result.faults:
        print(fault.message, file=sys.stderr, flush=True)
    kinds = ",".join(sorted({f.kind for f in result.faults})) or "-"
    print("result", result.outcome, result.sent, result.length, kinds, flush=True)
    return 0 if result.outcome == "done" else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], int(sys.argv[2])))
