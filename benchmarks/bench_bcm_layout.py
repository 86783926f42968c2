"""BCM layouts of a 3-axis cycle on vcan0: (one) one op holding whole cycles, 4 frames spaced
T/4 (what fieldbus.bcm_queue does), or (four) four ops of one frame each, all at T (each
cycle one burst from one timer interrupt). A reader process (python-can ``recv`` per frame,
or a raw socket drained per wake-up) reports its CPU time and wake-ups per cycle; the SYNC
intervals come from its kernel timestamps. 5 s per combination, T = 4 ms. Results and why
the four-op layout was not taken: docs/benchmarks.md, "Kernel-timed stream".

    scripts/with-vcan .venv/bin/python benchmarks/bench_bcm_layout.py
"""
import resource
import select
import socket
import struct
import subprocess
import sys
import time

import can
import numpy as np
from can.interfaces.socketcan import constants as bcm
from can.interfaces.socketcan.socketcan import build_bcm_header, create_bcm_socket

T = 0.004
IDS = [0x80, 0x201, 0x202, 0x203]
FRAME = struct.Struct("=IB3x8s")


def reader(mode, seconds):
    n = 0
    stamps = []
    t_end = time.time() + seconds + 1.0
    r0 = resource.getrusage(resource.RUSAGE_SELF)
    if mode == "pycan":
        bus = can.Bus(interface="socketcan", channel="vcan0")
        while time.time() < t_end:
            msg = bus.recv(0.1)
            if msg is not None:
                n += 1
                if msg.arbitration_id == 0x80:
                    stamps.append(msg.timestamp)
    else:
        sock = socket.socket(socket.PF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
        sock.setsockopt(socket.SOL_SOCKET, bcm.SO_TIMESTAMPNS, 1)
        sock.bind(("vcan0",))
        sock.setblocking(False)
        anc = socket.CMSG_SPACE(16)
        while time.time() < t_end:
            r, _, _ = select.select([sock], [], [], 0.1)
            if not r:
                continue
            while True:
                try:
                    data, ancdata, _, _ = sock.recvmsg(16, anc)
                except BlockingIOError:
                    break
                n += 1
                can_id = FRAME.unpack(data)[0]
                if can_id == 0x80:
                    sec, nsec = struct.unpack("@ll", ancdata[0][2])
                    stamps.append(sec + nsec * 1e-9)
    r1 = resource.getrusage(resource.RUSAGE_SELF)
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    d = np.diff(stamps) * 1000
    print(f"frames {n} syncs {len(stamps)} cpu {cpu:.2f}s = {cpu / max(len(stamps), 1) * 1e6:.0f} us/cycle"
          f" voluntary context switches/cycle {(r1.ru_nvcsw - r0.ru_nvcsw) / max(len(stamps), 1):.2f} | SYNC p50 {np.median(d):.3f} p99 {np.percentile(d, 99):.3f} max {d.max():.2f} ms",
          flush=True)


def frame(can_id):
    return FRAME.pack(can_id, 8 if can_id != 0x80 else 0, b"\0" * 8)


def sender(layout, seconds):
    cycles = int(seconds / T)
    socks = []
    if layout == "one":
        s = create_bcm_socket("vcan0")
        head = build_bcm_header(bcm.CAN_BCM_TX_SETUP, bcm.SETTIMER | bcm.STARTTIMER, cycles * 4, 0, round(T / 4 * 1e6), 0, 0, 0x80, 64 * 4)
        s.sendmsg([head, b"".join(frame(i) for _ in range(64) for i in IDS)])
        socks.append(s)
    else:
        s = create_bcm_socket("vcan0")
        for can_id in IDS:
            head = build_bcm_header(bcm.CAN_BCM_TX_SETUP, bcm.SETTIMER | bcm.STARTTIMER, cycles, 0, round(T * 1e6), 0, 0, can_id, 64)
            s.sendmsg([head, frame(can_id) * 64])
        socks.append(s)
    time.sleep(seconds + 0.5)
    for s in socks:
        s.close()


if __name__ == "__main__":
    if sys.argv[1:2] == ["reader"]:
        reader(sys.argv[2], float(sys.argv[3]))
    else:
        seconds = 5.0
        for layout in ("one", "four"):
            for mode in ("pycan", "drain"):
                r = subprocess.Popen([sys.executable, __file__, "reader", mode, str(seconds)], stdout=subprocess.PIPE, text=True)
                time.sleep(1.5)
                sender(layout, seconds)
                print(f"{layout:4} ops, reader {mode:5}:", r.communicate()[0].strip(), flush=True)
