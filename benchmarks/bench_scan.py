"""`drives scan` duration: listening, the 0x1000 probe of ids 1-127 and the reads of the nodes.

Simulated drives (nurbsmotion.sim, the packaged servo EDS) and a CiA-401 node on python-can's
virtual bus in the same process; the scan opens its own bus on the channel, as the CLI does.
Expected: listen_s + one SDO time-out (the silent ids) + the nodes' reads.

    PYTHONPATH=src python benchmarks/bench_scan.py --runs 5
    PYTHONPATH=src python benchmarks/bench_scan.py --drives 6 --listen-ms 1000 --sdo-timeout-ms 100
"""

from __future__ import annotations

import argparse
import os
import sys
import uuid
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._report import write_section  # noqa: E402

from nurbsmotion.fieldbus.scan import ScanSettings, open_network, scan_network  # noqa: E402
from nurbsmotion.sim import SimNetwork  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--drives", type=int, default=3)
    parser.add_argument("--listen-ms", type=int, default=1000)
    parser.add_argument("--sdo-timeout-ms", type=int, default=100)
    parser.add_argument("--no-write", action="store_true", help="do not update docs/benchmarks.md")
    args = parser.parse_args()
    settings = ScanSettings(listen_s=args.listen_ms / 1000, sdo_timeout_s=args.sdo_timeout_ms / 1000)
    channel = f"bench-scan-{uuid.uuid4().hex[:8]}"
    durations, found = [], []
    with SimNetwork(interface="virtual", channel=channel) as sim:
        for node_id in range(1, args.drives + 1):
            sim.add_drive(node_id)
        sim.add_io_node(100)
        for _ in range(args.runs):
            network = open_network("virtual", channel, 1_000_000)
            try:
                result = scan_network(network, settings)
            finally:
                network.disconnect()
            durations.append(result.duration_s)
            found.append(len(result.reports))
    d = np.array(durations)
    floor = settings.listen_s + settings.sdo_timeout_s
    load = os.getloadavg()[0]
    body = (f"{args.drives} simulated drives + 1 I/O node, listen {args.listen_ms} ms, SDO time-out "
            f"{args.sdo_timeout_ms} ms, {args.runs} scans, host load {load:.1f}: nodes found {sorted(set(found))}, "
            f"scan {d.min():.3f} / {np.median(d):.3f} / {d.max():.3f} s (min / median / max); listen + one "
            f"time-out = {floor:.3f} s, the rest is the nodes' reads (0x1018:01-04, 0x1008-0x100A, 0x6502).")
    print(body)
    if not args.no_write:
        write_section("scan", "`drives scan` on the virtual bus", body,
                      f"PYTHONPATH=src python benchmarks/bench_scan.py --runs {args.runs} --drives {args.drives}")


if __name__ == "__main__":
    main()
