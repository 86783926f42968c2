"""ETF + SO_TXTIME against the BCM ring (issue 14): the same 3-axis stream at T = 4 ms on vcan0,
run after run in alternation (A/B interleaved: the host's load changes under other agents' work).

- **bcm**: the product's writer, ``fieldbus.bcm_queue.BcmQueueWriter`` (one BCM op holding a
  ring of 64 cycles, SYNC then 3 RPDOs spaced T/4, lease renewed every wake-up, period
  trimmed from the echoed SYNCs), driven as the master drives it (horizon, commit, tail).
- **etf:D**: every frame sent ahead with an absolute CLOCK_TAI launch time
  (``benchmarks/etf_queue.py``: ``TxtimeSocket``) under an ETF qdisc of delta D µs: cycle k's SYNC at
  t0 + k·T + D, its RPDOs 1, 2, 3 µs later (one watchdog expiry sends the four, in order).
  The writer wakes every 8 ms (as the BCM writer) and keeps the frames of the cycles up to
  ``--horizon`` beyond the wire queued. Frames the qdisc dropped come from its error queue.

The writer runs in its own process (SCHED_FIFO 20, as the master's cycle thread); ``--stalls``
freezes it with SIGSTOP (the daemon stalled) at 1, 2, 3, ... s. An independent listener
process records every frame with its kernel timestamp, on vcan1: a reader of vcan0 cannot
time ETF frames (the echoed skb keeps its txtime as timestamp, so every interval reads T
exactly), so can-gw forwards every vcan0 frame to vcan1 without its stamp and the copy is
stamped when vcan0 delivers the original (this adds the guest's receive softirq delay to
both variants alike). A second column, "at transmit", times SYNC at the driver: a vcan0
reader's stamps for the BCM (stamped in vcan_tx), the driver's TX software stamps of the ETF
socket. Per run: SYNC interval p50/p99/max over the job, share outside ±5 % T, per drive the SYNC intervals with no RPDO (starved) or
with two (one overwritten), RPDOs that came after the next SYNC (a cycle split by a SYNC),
set-points lost on the wire, frames the qdisc dropped, cycles the ETF writer had to skip
(stall longer than its queue), the smallest RPDO→next SYNC margin, and SDO frames (0x601,
a plain socket every 20 ms) sent and seen. Load: the guest's and, with ``--host-load FILE``,
the host's /proc/loadavg as a host loop writes it into FILE (visible in the guest: hostfs).

``--setup`` (root, inside scripts/with-vcan) makes vcan0 echo in the driver (vcan echo=1, so
listeners see a frame when the qdisc lets it go, as on a real CAN controller) under a prio
qdisc whose band 0 is ETF (SO_PRIORITY 6) and band 1 a FIFO for everything else, and adds
vcan1 with the can-gw rule; both variants run on that same device:

    while :; do cat /proc/loadavg > /tmp/hostload.tmp; mv /tmp/hostload.tmp /tmp/hostload; sleep 1; done &
    scripts/with-vcan --timeout 1200 .venv/bin/python benchmarks/bench_etf.py --setup \
        --variants bcm,etf:2000 --runs 5 --stalls 0 --host-load /tmp/hostload
    ... --runs 2 --stalls 60,60,60,60,60

Results and the decision: docs/benchmarks-log.md "ETF + SO_TXTIME against the BCM ring",
docs/fieldbus.md "ETF or BCM".
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import re
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT))

from benchmarks.etf_queue import CAN_FRAME, TxtimeError, TxtimeSocket, tai_now_ns  # noqa: E402
from nurbsmotion.fieldbus.bcm_queue import WAKE_PERIOD_S, BcmQueueWriter  # noqa: E402
from nurbsmotion.fieldbus.cycle import DeadlineGrid, wait_until  # noqa: E402
from nurbsmotion.fieldbus.supervisor import CycleHistory  # noqa: E402
from nurbsmotion.fieldbus.writer import CyclicFrames  # noqa: E402
from nurbsmotion.runtime import CYCLE_THREAD_PRIORITY, set_thread_realtime  # noqa: E402
from nurbsmotion.can.socketcan_batch import BatchedSocketcanBus  # noqa: E402

CHANNEL = "vcan0"
LISTEN_CHANNEL = "vcan1"  # vcan0's frames forwarded by can-gw, stamped on arrival (module docstring)
RTM_NEWROUTE = 24
CGW_TYPE_CAN_CAN = 1
CGW_FLAGS_CAN_ECHO = 0x01
CGW_SRC_IF, CGW_DST_IF = 9, 10  # linux/can/gw.h
SYNC_ID = 0x80
SDO_ID = 0x601
NODES = (1, 2, 3)
RPDO_IDS = {0x200 + n: j for j, n in enumerate(NODES)}
CW_ENABLED = 0x000F
RPDO = struct.Struct("<Hi")  # controlword, set-point (here: the cycle number k)
STOP_CYCLES = 8  # the BCM writer's stop tail (cycles to rest) as the planner would give it
HISTORY_CYCLES = 512
SDO_PERIOD_S = 0.02
STALL_EVERY_S = 1.0
START_MARGIN_CYCLES = 3


def pack_rpdo(data: bytearray, cw: int, sp: int) -> None:
    RPDO.pack_into(data, 0, cw, sp)


# ---------------------------------------------------------------------------------- writers
def write_bcm(cycles: int, period_s: float, out: dict) -> None:
    """The product's BCM ring writer streaming set-point k in cycle k (k = 1..cycles, then held)."""
    frames = CyclicFrames([(0x200 + n, RPDO.size, j, pack_rpdo) for j, n in enumerate(NODES)])
    history = CycleHistory(HISTORY_CYCLES, len(NODES))
    writer = BcmQueueWriter(CHANNEL, frames, history, period_s, period_s, bus=None)  # type: ignore[arg-type]
    cw = [CW_ENABLED] * len(NODES)
    horizon = 0

    def tail(sp_rows: list[list[int]], cw_rows: list[list[int]]) -> int:
        for row in range(len(sp_rows)):
            sp_rows[row][:] = [min(horizon + 1 + row, cycles)] * len(NODES)
            cw_rows[row][:] = cw
        return 0

    def plan(c: int) -> int:
        nonlocal horizon
        first_new = horizon + 1
        horizon = writer.horizon(c, STOP_CYCLES, moving=True)
        for x in range(first_new, horizon + 1):
            history.store(x, cw, [min(x, cycles)] * len(NODES))
        return first_new

    writer.start()
    first_new = plan(0)
    writer.commit(0, horizon, first_new, tail)
    print("started", flush=True)
    c = 0
    while c < cycles + 2:
        c = writer.next_cycle()
        if writer.stalled():
            writer.restart(c)
            horizon = c
        first_new = plan(c)
        writer.commit(c, horizon, first_new, tail)
    out.update(expiries=writer.expired, headroom_min=writer.headroom.min, ring_cycles=writer.cycles)
    writer.close()


def etf_frames(k: int) -> list[bytes]:
    """SYNC and the three RPDOs of cycle k as can_frames."""
    rpdo = RPDO.pack(CW_ENABLED, k).ljust(8, b"\0")
    return [CAN_FRAME.pack(SYNC_ID, 0, b"")] + [CAN_FRAME.pack(can_id, RPDO.size, rpdo) for can_id in RPDO_IDS]


def write_etf(cycles: int, period_s: float, horizon: int, delta_us: int, out: dict) -> None:
    """Cycles 1..cycles with launch times t0 + k·T + delta (+1, 2, 3 µs for the RPDOs), queued
    up to ``horizon`` cycles beyond the wire at every wake-up; a stall longer than that skips
    the cycles whose time passed (counted)."""
    sock = TxtimeSocket(CHANNEL)
    period_ns, delta_ns = round(period_s * 1e9), delta_us * 1000
    t0_ns = tai_now_ns() + START_MARGIN_CYCLES * period_ns
    out.update(t0_wall_ns=t0_ns - (tai_now_ns() - time.time_ns()), period_ns=period_ns)
    grid = DeadlineGrid(WAKE_PERIOD_S, time.perf_counter())
    next_k, skipped, dropped = 1, 0, []
    print("started", flush=True)
    while next_k <= cycles:
        woke = wait_until(grid.next_s, 0.0)
        grid.advance(woke)
        k_wire = (tai_now_ns() - t0_ns) // period_ns  # the cycle whose wire time passed last
        if next_k <= k_wire + 1:
            skipped += k_wire + 2 - next_k
            next_k = k_wire + 2
        for k in range(next_k, min(cycles, k_wire + horizon) + 1):
            launch_ns = t0_ns + k * period_ns + delta_ns
            for j, frame in enumerate(etf_frames(k)):
                sock.send_at(frame, launch_ns + j * 1000, report_sent=j == 0)
            next_k = k + 1
        dropped += sock.drain_dropped()
    time.sleep(max(0.0, (t0_ns + (cycles + 2) * period_ns + delta_ns - tai_now_ns()) / 1e9))
    dropped += sock.drain_dropped()
    out.update(skipped=skipped, refused=sock.refused, sync_sent=sock.sent_stamps,
               dropped_missed=sum(d.reason is TxtimeError.MISSED for d in dropped),
               dropped_invalid=sum(d.reason is TxtimeError.INVALID_PARAM for d in dropped),
               dropped_sync=sum(d.can_id == SYNC_ID for d in dropped))
    sock.close()


def run_writer(variant: str, cycles: int, period_s: float, horizon: int) -> int:
    gc.collect()
    gc.freeze()
    out: dict = {"policy": set_thread_realtime(CYCLE_THREAD_PRIORITY)}
    if variant == "bcm":
        write_bcm(cycles, period_s, out)
    else:
        write_etf(cycles, period_s, horizon, int(variant.split(":")[1]), out)
    print("result", json.dumps(out), flush=True)
    return 0


# ---------------------------------------------------------------------------------- listener
def run_listener(path: str, channel: str, sync_only: bool) -> int:
    """Every SYNC, RPDO and SDO frame (or only SYNC) with its kernel timestamp until SIGUSR1,
    then saved."""
    stop = threading.Event()
    signal.signal(signal.SIGUSR1, lambda *_: stop.set())
    bus = BatchedSocketcanBus(channel, can_filters=[{"can_id": SYNC_ID, "can_mask": 0x7FF}] if sync_only else None)
    stamps, ids, values = [], [], []
    print("ready", flush=True)
    while True:
        msg = bus.recv(0.0 if stop.is_set() else 0.1)
        if msg is None:
            if stop.is_set():
                break
            continue
        can_id = msg.arbitration_id
        if can_id == SYNC_ID or can_id == SDO_ID or can_id in RPDO_IDS:
            stamps.append(msg.timestamp)
            ids.append(can_id)
            values.append(RPDO.unpack_from(bytes(msg.data))[1] if can_id in RPDO_IDS else 0)
    bus.shutdown()
    np.savez(path, stamps=np.array(stamps), ids=np.array(ids), values=np.array(values))
    return 0


# ---------------------------------------------------------------------------------- analysis
@dataclass
class RunFigures:
    variant: str
    stalls: str
    held_ms: list[float]
    intervals_ms: np.ndarray
    outside_share: float
    starved: int  # (drive, SYNC interval) with no RPDO
    doubled: int  # RPDOs overwritten by a second one of the same drive before the next SYNC
    split: int  # RPDOs of cycle k after a SYNC that followed another drive's RPDO of k
    lost: list[int]
    margin_ms: float
    launch_ms: np.ndarray  # ETF: RPDO1 stamp - planned wire time of its cycle
    transmit_ms: np.ndarray  # SYNC intervals at the driver's transmit (vcan0 stamps / ETF TX stamps)
    sdo_sent: int
    sdo_seen: int
    sdo_max_ms: float
    writer: dict
    qdisc_dropped: int
    load: str
    period_ms: float
    outcome: str = "done"

    def row(self) -> str:
        d = self.intervals_ms
        w = self.writer
        if self.variant == "bcm":
            queue = f"expiries {w.get('expiries', '?')}, headroom min {w.get('headroom_min', '?')}/{w.get('ring_cycles', '?')}"
        else:
            queue = (f"dropped {w.get('dropped_missed', 0)}+{w.get('dropped_invalid', 0)} (SYNC {w.get('dropped_sync', 0)}), "
                     f"qdisc {self.qdisc_dropped}, skipped {w.get('skipped', 0)}")
        launch = (f"{np.median(self.launch_ms):.3f}/{np.percentile(self.launch_ms, 99):.3f}/{self.launch_ms.max():.2f}"
                  if len(self.launch_ms) else "-")
        held = "/".join(f"{h:.0f}" for h in self.held_ms) or "-"
        t = self.transmit_ms
        return (f"| {self.variant} | {held} | {self.load} | {np.median(d):.3f} | {np.percentile(d, 99):.3f} | "
                f"{d.max():.2f} | {self.outside_share * 100:.1f} | {t.min():.3f} / {np.percentile(t, 99):.3f} / {t.max():.2f} / "
                f"{np.mean(np.abs(t - self.period_ms) > 0.05 * self.period_ms) * 100:.1f} | {self.starved} | {self.doubled} | {self.split} | "
                f"{'/'.join(map(str, self.lost))} | {self.margin_ms:.3f} | {launch} | {queue} | "
                f"{self.sdo_seen}/{self.sdo_sent}, max {self.sdo_max_ms:.1f} ms |")


HEADER = ("| writer | stalls held ms | load guest / host | SYNC p50 ms | p99 ms | max ms | outside ±5 % T % | "
          "at transmit min / p99 / max ms / outside % | starved | overwritten | split | lost X/Y/Z | min RPDO→SYNC ms | launch late p50/p99/max ms | "
          "queue | SDO seen/sent |\n" + "|---" * 16 + "|")


def analyse_wire(stamps: np.ndarray, ids: np.ndarray, values: np.ndarray, cycles: int, period_s: float) -> dict:
    """The drive's view of the job (cycles 1..cycles) from the listener's frames."""
    sync_stamps = stamps[ids == SYNC_ID]
    is_rpdo = np.isin(ids, list(RPDO_IDS))
    r_stamp, r_node, r_k = stamps[is_rpdo], np.array([RPDO_IDS[i] for i in ids[is_rpdo]], dtype=int), values[is_rpdo]
    r_interval = np.searchsorted(sync_stamps, r_stamp, side="right") - 1  # SYNC interval each RPDO fell in
    in_job = (r_k >= 1) & (r_k <= cycles)
    first = int(r_interval[in_job].min())
    last = int(r_interval[in_job & (r_k == r_k[in_job].max())].min())  # the job's end (then held)
    intervals = np.diff(sync_stamps[first:last + 2])
    counts = np.zeros((last - first + 1, len(NODES)), dtype=int)
    span = in_job & (r_interval >= first) & (r_interval <= last)
    np.add.at(counts, (r_interval[span] - first, r_node[span]), 1)
    earliest = {}
    for k, i in zip(r_k[span], r_interval[span]):
        earliest[k] = min(earliest.get(k, i), i)
    split = int(sum(i > earliest[k] for k, i in zip(r_k[span], r_interval[span])))
    lost = [int(cycles - len(set(r_k[in_job & (r_node == j)].tolist()))) for j in range(len(NODES))]
    last_rpdo = {}
    for i, s in zip(r_interval[span], r_stamp[span]):
        last_rpdo[i] = max(last_rpdo.get(i, s), s)
    margins = [sync_stamps[i + 1] - s for i, s in last_rpdo.items() if i + 1 < len(sync_stamps)]
    return dict(intervals_ms=intervals * 1000,
                outside_share=float(np.mean(np.abs(intervals - period_s) > 0.05 * period_s)),
                starved=int((counts == 0).sum()), doubled=int(np.clip(counts - 1, 0, None).sum()), split=split,
                lost=lost, margin_ms=min(margins) * 1000 if margins else float("nan"),
                rpdo1=(r_stamp[in_job & (r_node == 0)], r_k[in_job & (r_node == 0)]))


# ---------------------------------------------------------------------------------- device
def sh(command: str) -> str:
    result = subprocess.run(command, shell=True, capture_output=True, text=True)
    if result.returncode:
        raise SystemExit(f"bench_etf: '{command}' failed: {result.stderr.strip()}")
    return result.stdout


def load_module(path: str, *params: str) -> None:
    uml = Path(f"/usr/lib/uml/modules/{os.uname().release}/kernel/{path}.ko")
    name = Path(path).name
    if uml.exists():
        subprocess.run(["insmod", str(uml), *params], capture_output=True)
    else:
        subprocess.run(["modprobe", name, *params], capture_output=True)


def setup_device(delta_us: int) -> None:
    """vcan0 echoing in the driver, root prio qdisc: band 0 ETF (SO_PRIORITY 6), band 1 FIFO;
    every frame of vcan0 forwarded to vcan1 for the listener (module docstring)."""
    subprocess.run("ip link del dev vcan0; rmmod vcan", shell=True, capture_output=True)
    load_module("drivers/net/can/vcan", "echo=1")
    load_module("net/sched/sch_prio")
    load_module("net/sched/sch_etf")
    load_module("net/can/can-gw")
    for dev in (CHANNEL, LISTEN_CHANNEL):
        sh(f"ip link add dev {dev} type vcan && ip link set dev {dev} txqueuelen 1000 && ip link set up dev {dev}")
    print(f"ETF as the root qdisc, a frame without a launch time: {plain_send_under_root_etf(delta_us)}", flush=True)
    sh("tc qdisc add dev vcan0 root handle 1: prio bands 2 priomap 1 1 1 1 1 1 0 1 1 1 1 1 1 1 1 1")
    set_delta(delta_us)
    add_can_gateway(CHANNEL, LISTEN_CHANNEL)


def plain_send_under_root_etf(delta_us: int) -> str:
    """What an SDO's send does while ETF is vcan0's root qdisc (then removed again)."""
    sh(f"tc qdisc add dev vcan0 root etf clockid CLOCK_TAI delta {delta_us * 1000}")
    with socket.socket(socket.PF_CAN, socket.SOCK_RAW, socket.CAN_RAW) as plain:
        plain.bind((CHANNEL,))
        try:
            plain.send(CAN_FRAME.pack(SDO_ID, 8, bytes(8)))
            outcome = "sent"
        except OSError as err:
            outcome = f"refused, {err.strerror} (errno {err.errno})"
    sh("tc qdisc del dev vcan0 root")
    return outcome


def add_can_gateway(src: str, dst: str) -> None:
    """can-gw rule src -> dst (RTM_NEWROUTE, AF_CAN, CGW_TYPE_CAN_CAN), echoed on dst so its
    readers get the frame, without CGW_FLAGS_CAN_SRC_TSTAMP: the copy is stamped afresh when
    it reaches dst, i.e. when src delivered the original (what `cangw -A -s src -d dst -e` does)."""
    attrs = b"".join(struct.pack("=HHI", 8, kind, socket.if_nametoindex(dev))
                     for kind, dev in ((CGW_SRC_IF, src), (CGW_DST_IF, dst)))
    body = struct.pack("=BBH", socket.AF_CAN, CGW_TYPE_CAN_CAN, CGW_FLAGS_CAN_ECHO) + attrs
    NLM_F_REQUEST, NLM_F_ACK = 1, 4
    message = struct.pack("=IHHII", 16 + len(body), RTM_NEWROUTE, NLM_F_REQUEST | NLM_F_ACK, 1, 0) + body
    with socket.socket(socket.AF_NETLINK, socket.SOCK_RAW, socket.NETLINK_ROUTE) as nl:
        nl.sendto(message, (0, 0))
        reply = nl.recv(4096)
    error = struct.unpack_from("=i", reply, 16)[0]
    if error:
        raise SystemExit(f"bench_etf: can-gw {src} -> {dst} refused: {os.strerror(-error)}")


def set_delta(delta_us: int) -> None:
    """ETF of this delta on band 0 (ETF cannot change its parameters: a new qdisc)."""
    if f"delta {delta_us * 1000} " in sh("tc qdisc show dev vcan0"):
        return
    subprocess.run("tc qdisc del dev vcan0 parent 1:1", shell=True, capture_output=True)
    sh(f"tc qdisc add dev vcan0 parent 1:1 handle 10: etf clockid CLOCK_TAI delta {delta_us * 1000}")


def qdisc_dropped() -> int:
    """Frames the ETF qdisc has dropped so far (tc -s)."""
    text = sh("tc -s qdisc show dev vcan0")
    match = re.search(r"qdisc etf .*?dropped (\d+)", text, re.S)
    return int(match.group(1)) if match else 0


def host_load(path: str | None) -> str:
    if not path:
        return "-"
    try:
        return Path(path).read_text().split()[0]
    except (OSError, IndexError):
        return "?"


# ---------------------------------------------------------------------------------- one run
@dataclass
class Disturbance:
    """SDO frames from a plain socket every 20 ms, and the writer's stalls (SIGSTOP)."""

    stall_ms: list[float]
    sdo_sent: list[float] = field(default_factory=list)
    held_ms: list[float] = field(default_factory=list)

    def run(self, writer_pid: int, seconds: float, done: threading.Event) -> None:
        sdo = socket.socket(socket.PF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
        sdo.bind((CHANNEL,))
        start = time.perf_counter()
        stalls = [(STALL_EVERY_S * (n + 1), ms) for n, ms in enumerate(self.stall_ms)]
        while not done.is_set() and time.perf_counter() - start < seconds:
            if stalls and time.perf_counter() - start >= stalls[0][0]:
                _, ms = stalls.pop(0)
                t = time.perf_counter()
                os.kill(writer_pid, signal.SIGSTOP)
                time.sleep(ms / 1000)
                os.kill(writer_pid, signal.SIGCONT)
                self.held_ms.append((time.perf_counter() - t) * 1000)
            self.sdo_sent.append(time.time())
            sdo.send(CAN_FRAME.pack(SDO_ID, 8, bytes([0x40, 0x41, 0x60, 0, 0, 0, 0, 0])))
            time.sleep(SDO_PERIOD_S)
        sdo.close()


def one_run(variant: str, stall_ms: list[float], args: argparse.Namespace, n: int) -> RunFigures:
    period_s = args.period_ms / 1000
    cycles = round(args.seconds / period_s)
    if variant != "bcm":
        set_delta(int(variant.split(":")[1]))
    dropped_before = qdisc_dropped()
    load = f"{os.getloadavg()[0]:.2f} / {host_load(args.host_load)}"
    path = f"{args.folder}/listen-{n}.npz"
    listeners = [subprocess.Popen([sys.executable, __file__, "--role", "listener", "--out", out, "--listen", channel, *extra],
                                  stdout=subprocess.PIPE, text=True)
                 for out, channel, extra in ((path, args.listen, []), (path + ".tx.npz", CHANNEL, ["--sync-only"]))]
    for listener in listeners:
        assert listener.stdout is not None
        listener.stdout.readline()
    writer = subprocess.Popen([sys.executable, __file__, "--role", "writer", "--variant", variant,
                               "--cycles", str(cycles), "--period-ms", str(args.period_ms), "--horizon", str(args.horizon)],
                              stdout=subprocess.PIPE, text=True)
    assert writer.stdout is not None
    writer.stdout.readline()
    disturbance, done = Disturbance(stall_ms), threading.Event()
    thread = threading.Thread(target=disturbance.run, args=(writer.pid, args.seconds + 1.0, done))
    thread.start()
    lines = writer.stdout.read().splitlines()
    writer.wait()
    done.set()
    thread.join()
    time.sleep(0.3)
    for listener in listeners:
        listener.send_signal(signal.SIGUSR1)
    for listener in listeners:
        listener.wait(60)
    result = next((json.loads(line.split(" ", 1)[1]) for line in lines if line.startswith("result ")), {})
    data = np.load(path)
    stamps, ids, values = data["stamps"], data["ids"], data["values"]
    wire = analyse_wire(stamps, ids, values, cycles, period_s)
    r1_stamp, r1_k = wire.pop("rpdo1")
    launch = (r1_stamp - (result["t0_wall_ns"] + r1_k * result["period_ns"]) / 1e9 - 1e-6) * 1000 \
        if "t0_wall_ns" in result else np.array([])
    syncs = stamps[ids == SYNC_ID]
    if "sync_sent" in result:  # ETF: the driver's transmit stamps (vcan0 readers get the txtime)
        sent = np.array(result.pop("sync_sent"))
    else:  # BCM: a vcan0 reader's stamps are the transmit times
        sent = np.load(path + ".tx.npz")["stamps"]
    in_job = sent[(sent >= syncs[0] - period_s / 2) & (sent <= syncs[-1])]
    wire["transmit_ms"] = np.diff(in_job) * 1000
    sdo_stamps = stamps[ids == SDO_ID]
    sent = disturbance.sdo_sent
    sdo_max = max((s - t for s, t in zip(sdo_stamps, sent)), default=float("nan")) * 1000 \
        if len(sdo_stamps) == len(sent) else float("nan")
    return RunFigures(variant, ",".join(f"{s:g}" for s in stall_ms) or "0", disturbance.held_ms, launch_ms=launch,
                      sdo_sent=len(sent), sdo_seen=len(sdo_stamps), sdo_max_ms=sdo_max, writer=result,
                      qdisc_dropped=qdisc_dropped() - dropped_before, load=load, period_ms=args.period_ms,
                      outcome="done" if writer.returncode == 0 else f"writer exit {writer.returncode}", **wire)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--role", default="bench", choices=("bench", "writer", "listener"))
    parser.add_argument("--variant", default="bcm")
    parser.add_argument("--variants", default="bcm,etf:2000", help="comma list of bcm, etf:DELTA_US (alternated)")
    parser.add_argument("--runs", type=int, default=5, help="runs of each variant")
    parser.add_argument("--stalls", default="0", help="stall lengths of one run in ms, one per second (0: none)")
    parser.add_argument("--seconds", type=float, default=6.0, help="job length")
    parser.add_argument("--period-ms", type=float, default=4.0)
    parser.add_argument("--horizon", type=int, default=16, help="ETF: cycles queued beyond the wire")
    parser.add_argument("--cycles", type=int, default=0)
    parser.add_argument("--setup", action="store_true", help="(root) configure vcan0: echo=1, prio + etf")
    parser.add_argument("--host-load", help="file holding the host's /proc/loadavg")
    parser.add_argument("--folder", default="/tmp/bench-etf")
    parser.add_argument("--out")
    parser.add_argument("--sync-only", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--listen", default=LISTEN_CHANNEL,
                        help="listener's channel (vcan0 itself: ETF frames carry their txtime as rx stamp)")
    args = parser.parse_args()
    if args.role == "writer":
        return run_writer(args.variant, args.cycles, args.period_ms / 1000, args.horizon)
    if args.role == "listener":
        return run_listener(args.out, args.listen, args.sync_only)
    variants = args.variants.split(",")
    delta0 = next((int(v.split(":")[1]) for v in variants if v != "bcm"), 2000)
    if args.setup:
        setup_device(delta0)
    Path(args.folder).mkdir(parents=True, exist_ok=True)
    stall_ms = [float(s) for s in args.stalls.split(",") if float(s) > 0]
    print(f"{time.strftime('%Y-%m-%d %H:%M:%S UTC', time.gmtime())}, T = {args.period_ms:g} ms, 3 axes, "
          f"{args.seconds:g} s jobs, ETF horizon {args.horizon} cycles, stalls {stall_ms or 'none'}", flush=True)
    print(HEADER, flush=True)
    figures = []
    for n in range(args.runs):
        for variant in variants:
            run = one_run(variant, stall_ms, args, len(figures))
            figures.append(run)
            print(run.row(), flush=True)
    for variant in variants:
        mine = [f for f in figures if f.variant == variant]
        p99 = [np.percentile(f.intervals_ms, 99) for f in mine]
        print(f"{variant}: p99 {min(p99):.3f}-{max(p99):.3f} ms, max {max(f.intervals_ms.max() for f in mine):.2f} ms, "
              f"at transmit min {min(f.transmit_ms.min() for f in mine):.3f} ms, "
              f"starved {sum(f.starved for f in mine)}, overwritten {sum(f.doubled for f in mine)}, "
              f"split {sum(f.split for f in mine)}, lost {sum(sum(f.lost) for f in mine)}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
