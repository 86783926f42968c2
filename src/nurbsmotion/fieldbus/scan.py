"""Find the nodes on a CANopen bus and read what they are (``nurbsmotion drives scan``).

Two parts. Pure: decoding 0x1000 (device type), 0x1018 (identity), 0x6502 (supported drive
modes), heartbeat state bytes and expedited SDO upload answers. I/O: listen for boot-up and
heartbeat frames (0x700 + id), then read 0x1000:00 of every id 1-127 at once (one expedited
upload request per id, the answers collected for one SDO time-out), then read the rest of
each answering node with canopen's SDO client.

What the scan sends (CiA 301): SDO upload (read) requests only, and after a read that got no
answer within the time-out canopen's SDO abort 0x05040000 for that transfer. No NMT command,
no SDO download, no SYNC, no PDO: no node changes its NMT or CiA-402 state. A node in
STOPPED answers no SDO (CiA 301): it shows by its heartbeat only.
"""

from __future__ import annotations

import logging
import statistics
import struct
import threading
import time
from collections.abc import Iterable
from dataclasses import dataclass, field

import can
import canopen
from canopen.objectdictionary import ObjectDictionary
from canopen.sdo import SdoAbortedError, SdoClient, SdoCommunicationError

from nurbsmotion.can import cia402 as c
from nurbsmotion.errors import FieldbusError
from nurbsmotion.log import kv

log = logging.getLogger(__name__)

ALL_NODE_IDS = tuple(range(1, 128))

# CiA 301 device profile numbers (0x1000 bits 0-15) met on machine buses.
PROFILE_NAMES = {401: "CiA 401 I/O", 402: "CiA 402 drive", 404: "CiA 404 measuring device", 406: "CiA 406 encoder"}
PROFILE_IO, PROFILE_DRIVE = 401, 402

# CiA 402-2, 0x1000 bits 16-23: type of drive.
DRIVE_TYPES = {0x01: "frequency converter", 0x02: "servo drive", 0x03: "stepper motor", 0xFF: "multiple device module"}

# CiA 401, 0x1000 bits 16-19: the I/O functions the device has.
IO_FUNCTIONS = ((0, "digital in"), (1, "digital out"), (2, "analogue in"), (3, "analogue out"))

# CiA 402 0x6502 bits and the 0x6060 mode abbreviations (bits 16-31 are manufacturer specific).
MODE_BITS = ((0, "pp"), (1, "vl"), (2, "pv"), (3, "tq"), (5, "hm"), (6, "ip"), (7, "csp"), (8, "csv"),
             (9, "cst"), (10, "cstca"))

# Vendor ids (0x1018:01) and names, from the [DeviceInfo] VendorNumber / VendorName of the
# EDS files in tests/data/eds (SOURCES.md) and eds/. Vendor id 0 is unassigned (the project's
# own servo and SCHUNK's PRL120 file both use it) and is not named.
VENDOR_NAMES = {
    0x0000009A: "Elmo Motion Control",
    0x000000FB: "maxon motor ag",
    0x00000147: "Faulhaber",
    0x000001A3: "Technosoft",
    0x0000026C: "Nanotec Electronic GmbH & Co. KG",
    0x5A65726F: "ZEROERR CONTROL",
}

# SDO abort codes that mean "this optional object is not there" (CiA 301 table 22).
ABORT_NO_OBJECT = 0x06020000
ABORT_NO_SUBINDEX = 0x06090011
_ABSENT = (ABORT_NO_OBJECT, ABORT_NO_SUBINDEX)


# ------------------------------------------------------------------ pure decoding


@dataclass(frozen=True)
class DeviceType:
    """0x1000: bits 0-15 the device profile number, bits 16-31 additional information."""

    raw: int

    @property
    def profile(self) -> int:
        return self.raw & 0xFFFF

    @property
    def additional(self) -> int:
        return self.raw >> 16

    def describe(self) -> str:
        """``CiA 402 drive, servo drive`` / ``CiA 401 I/O, digital in + digital out``."""
        name = PROFILE_NAMES.get(self.profile, f"profile {self.profile}" if self.profile else "no profile")
        if self.profile == PROFILE_DRIVE:
            kind = DRIVE_TYPES.get(self.additional & 0xFF)
            return f"{name}, {kind}" if kind else name
        if self.profile == PROFILE_IO:
            functions = [text for bit, text in IO_FUNCTIONS if self.additional >> bit & 1]
            return f"{name}, {' + '.join(functions)}" if functions else name
        return name


@dataclass(frozen=True)
class Identity:
    """0x1018: sub 1 vendor id (mandatory), 2 product code, 3 revision, 4 serial (optional)."""

    vendor_id: int
    product_code: int | None = None
    revision: int | None = None
    serial: int | None = None

    def vendor(self) -> str:
        """``0x000000FB (maxon motor ag)``, or the bare number for an unknown vendor."""
        name = VENDOR_NAMES.get(self.vendor_id)
        return f"0x{self.vendor_id:08X} ({name})" if name else f"0x{self.vendor_id:08X}"


def supported_modes(value: int) -> tuple[str, ...]:
    """The CiA-402 modes whose 0x6502 bit is set (``pp``, ``ip``, ``csp``, ...), in bit order;
    manufacturer-specific bits 16-31 as ``vendor bit n``."""
    names = [name for bit, name in MODE_BITS if value >> bit & 1]
    return tuple(names + [f"vendor bit {bit}" for bit in range(16, 32) if value >> bit & 1])


def nmt_state_name(state_byte: int | None) -> str:
    """Heartbeat state byte (CiA 301 7.2.8.3.2.1) in words; ``-`` when none was heard."""
    if state_byte is None:
        return "-"
    try:
        return c.NmtState(state_byte & 0x7F).name.replace("_", "-")
    except ValueError:
        return f"state 0x{state_byte:02X}"


@dataclass(frozen=True)
class SdoAnswer:
    """One answer to an expedited upload request: the data, or the abort code, or a
    segmented transfer announced (the value is longer than 4 bytes)."""

    data: bytes | None = None
    abort_code: int | None = None
    segmented: bool = False


SDO_UPLOAD_REQUEST = 0x40  # ccs 2: initiate upload (CiA 301 7.2.4.3.6)
SDO_ABORT = 0x80


def upload_request(index: int, subindex: int) -> bytes:
    """The 8-byte initiate upload request of (index, subindex)."""
    return struct.pack("<BHB4x", SDO_UPLOAD_REQUEST, index, subindex)


def parse_upload_answer(data: bytes, index: int, subindex: int) -> SdoAnswer | None:
    """Decode a server's answer to :func:`upload_request`; None for a frame that is not an
    answer about (index, subindex) (a stale or foreign frame on the same COB-ID)."""
    if len(data) != 8 or struct.unpack_from("<HB", data, 1) != (index, subindex):
        return None
    command = data[0]
    if command == SDO_ABORT:
        return SdoAnswer(abort_code=struct.unpack_from("<I", data, 4)[0])
    if command >> 5 != 2:  # scs 2: initiate upload response
        return None
    if not command & 0x02:  # e = 0: segmented, the size (if s) in bytes 4-7
        return SdoAnswer(segmented=True)
    size = 4 - (command >> 2 & 0x03) if command & 0x01 else 4
    return SdoAnswer(data=bytes(data[4:4 + size]))


def abort_text(code: int) -> str:
    return f"SDO abort 0x{code:08X} ({SdoAbortedError.CODES.get(code, 'unknown abort code')})"


# ------------------------------------------------------------------ what a node is


@dataclass(frozen=True)
class NodeReport:
    """What the scan learnt about one node id. ``problems`` are one line each (an object that
    should be there and was refused, or silence); optional objects a node lacks are None."""

    node_id: int
    nmt_state: int | None = None  # last heartbeat / boot-up state byte heard
    heartbeat_period_s: float | None = None
    device_type: DeviceType | None = None
    identity: Identity | None = None
    device_name: str | None = None  # 0x1008
    hardware_version: str | None = None  # 0x1009
    software_version: str | None = None  # 0x100A
    modes: int | None = None  # 0x6502 (CiA 402 drives)
    answered_sdo: bool = False
    problems: tuple[str, ...] = ()

    @property
    def profile(self) -> int | None:
        return self.device_type.profile if self.device_type else None

    def status(self) -> str:
        """How the node answered: the CLI's last column."""
        if self.answered_sdo:
            return "answers SDO" + (f"; {len(self.problems)} problem(s)" if self.problems else "")
        if self.nmt_state == c.NmtState.STOPPED:
            return "heartbeat only: NMT STOPPED answers no SDO"
        return "heartbeat only: no SDO answer"


# ------------------------------------------------------------------ listening


# The scan's callbacks stay subscribed until the network is disconnected, switched off by a
# flag: canopen's Network.notify looks a COB-ID up twice (``in``, then ``[]``), so removing the
# last callback of an id while a frame of it is dispatched raises KeyError in the receive
# thread, which stops python-can's notifier (late SDO answers and heartbeats do arrive then).


class HeartbeatWatch:
    """Boot-up and heartbeat frames (COB-ID 0x700 + id) of the given ids, as heard."""

    def __init__(self, network: canopen.Network, node_ids: Iterable[int]) -> None:
        self._network = network
        self._ids = tuple(node_ids)
        self._lock = threading.Lock()
        self._heard: dict[int, list[tuple[float, int]]] = {}
        self._listening = False

    def start(self) -> None:
        self._listening = True
        for node_id in self._ids:
            self._network.subscribe(c.COB_HEARTBEAT + node_id, self._on_frame)

    def stop(self) -> None:
        self._listening = False  # not unsubscribed: see above

    def _on_frame(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if self._listening and len(data) >= 1:
            with self._lock:
                self._heard.setdefault(can_id - c.COB_HEARTBEAT, []).append((timestamp, data[0] & 0x7F))

    def node_ids(self) -> set[int]:
        with self._lock:
            return set(self._heard)

    def state(self, node_id: int) -> int | None:
        with self._lock:
            beats = self._heard.get(node_id)
            return beats[-1][1] if beats else None

    def period_s(self, node_id: int) -> float | None:
        """Median interval between the heartbeats heard (boot-ups excluded); None below two."""
        with self._lock:
            times = [t for t, state in self._heard.get(node_id, []) if state != c.NmtState.BOOTUP]
        intervals = [b - a for a, b in zip(times, times[1:]) if b > a]
        return statistics.median(intervals) if intervals else None


# ------------------------------------------------------------------ reading


@dataclass(frozen=True)
class ScanSettings:
    """``listen_s``: heartbeats are listened for this long before the SDO reads (and on
    during them); ``sdo_timeout_s``: one SDO answer (the probe of all ids waits this long once)."""

    listen_s: float = 1.0
    sdo_timeout_s: float = 0.1
    node_ids: tuple[int, ...] = ALL_NODE_IDS
    send_retry_s: float = 0.002  # a full transmit queue (ENOBUFS on can0: txqueuelen 10): wait, resend
    send_attempts: int = 50


def probe_device_types(network: canopen.Network, node_ids: Iterable[int], settings: ScanSettings
                       ) -> dict[int, SdoAnswer]:
    """Read 0x1000:00 of every id at once: one upload request per id, then the answers for one
    SDO time-out after the last request. Ids without an answer are absent from the result."""
    ids = tuple(node_ids)
    answers: dict[int, SdoAnswer] = {}
    done = threading.Event()
    lock = threading.Lock()

    def on_answer(can_id: int, data: bytearray, timestamp: float) -> None:
        answer = parse_upload_answer(bytes(data), c.DEVICE_TYPE, 0)
        with lock:
            if answer is not None and not done.is_set():
                answers.setdefault(can_id - c.COB_SDO_TX, answer)
                if len(answers) == len(ids):
                    done.set()

    for node_id in ids:  # not unsubscribed afterwards (see HeartbeatWatch): switched off by ``done``
        network.subscribe(c.COB_SDO_TX + node_id, on_answer)
    try:
        for node_id in ids:
            _send(network, c.COB_SDO_RX + node_id, upload_request(c.DEVICE_TYPE, 0), settings)
        done.wait(settings.sdo_timeout_s)
    finally:
        with lock:
            done.set()  # later answers are ignored from here on
    return dict(answers)


def _send(network: canopen.Network, can_id: int, data: bytes, settings: ScanSettings) -> None:
    """Send one frame; a full transmit queue is waited out (real can0 queues only 10 frames).
    FieldbusError (one line) when it stays full: a bus-off or down interface."""
    for attempt in range(settings.send_attempts):
        try:
            network.send_message(can_id, data)
            return
        except can.CanError as err:
            if attempt == settings.send_attempts - 1:
                raise FieldbusError(f"cannot send the SDO request 0x{can_id:03X} after {settings.send_attempts} "
                                    f"attempts ({' '.join(str(err).split())}): is the interface up, the bitrate "
                                    "right and a node acknowledging frames?") from None
            time.sleep(settings.send_retry_s)


class SdoReader:
    """The SDO reads of one node through canopen's SDO client (no RemoteNode: nothing but the
    node's SDO answers is subscribed); the first silence ends the node's reads (a node that
    stopped answering is not asked again and again)."""

    def __init__(self, network: canopen.Network, node_id: int, timeout_s: float) -> None:
        self.node_id = node_id
        self.sdo = SdoClient(c.COB_SDO_RX + node_id, c.COB_SDO_TX + node_id, ObjectDictionary())
        self.sdo.network = network
        self.sdo.RESPONSE_TIMEOUT = timeout_s
        self.sdo.MAX_RETRIES = 1
        self._active = True
        network.subscribe(c.COB_SDO_TX + node_id, self._on_response)  # never unsubscribed: see HeartbeatWatch
        self.problems: list[str] = []
        self.silent = False

    def _on_response(self, can_id: int, data: bytearray, timestamp: float) -> None:
        if self._active:
            self.sdo.on_response(can_id, data, timestamp)

    def close(self) -> None:
        self._active = False

    def raw(self, index: int, subindex: int, what: str, optional: bool) -> bytes | None:
        if self.silent:
            return None
        try:
            return self.sdo.upload(index, subindex)
        except SdoAbortedError as err:
            if not (optional and err.code in _ABSENT):
                self.problems.append(f"0x{index:04X}:{subindex:02X} ({what}): {abort_text(err.code)}")
        except SdoCommunicationError as err:
            self.silent = True
            self.problems.append(f"0x{index:04X}:{subindex:02X} ({what}): no SDO answer ({err}); "
                                 "later objects not read")
        except can.CanError as err:  # the request could not be sent (bus-off, transmit queue full)
            self.silent = True
            self.problems.append(f"0x{index:04X}:{subindex:02X} ({what}): cannot send the request "
                                 f"({' '.join(str(err).split())}); later objects not read")
        return None

    def u32(self, index: int, subindex: int, what: str, optional: bool = False) -> int | None:
        data = self.raw(index, subindex, what, optional)
        if data is None:
            return None
        if not 1 <= len(data) <= 4:
            self.problems.append(f"0x{index:04X}:{subindex:02X} ({what}): {len(data)} bytes, expected at most 4")
            return None
        return int.from_bytes(data, "little")

    def text(self, index: int, what: str) -> str | None:
        data = self.raw(index, 0, what, optional=True)
        return data.split(b"\x00", 1)[0].decode("latin-1").strip() if data is not None else None


def read_node(network: canopen.Network, node_id: int, settings: ScanSettings,
              probe: SdoAnswer | None = None) -> NodeReport:
    """Everything the scan reads of one node (0x1000, 0x1018:01-04, 0x1008, 0x1009, 0x100A and,
    for a CiA 402 drive, 0x6502); ``probe`` is the 0x1000 answer already received."""
    reader = SdoReader(network, node_id, settings.sdo_timeout_s)
    try:
        if probe is not None and probe.data is not None:
            device_raw: int | None = int.from_bytes(probe.data, "little")
        elif probe is not None and probe.abort_code is not None:
            reader.problems.append(f"0x1000:00 (device type): {abort_text(probe.abort_code)}")
            device_raw = None
        else:
            device_raw = reader.u32(c.DEVICE_TYPE, 0, "device type")
        answered = probe is not None or not reader.silent
        vendor = reader.u32(c.IDENTITY, 1, "vendor id")
        product = reader.u32(c.IDENTITY, 2, "product code")
        revision = reader.u32(c.IDENTITY, 3, "revision", optional=True)
        serial = reader.u32(c.IDENTITY, 4, "serial number", optional=True)
        device_type = DeviceType(device_raw) if device_raw is not None else None
        name, hardware, software = (reader.text(0x1008, "device name"), reader.text(0x1009, "hardware version"),
                                    reader.text(0x100A, "software version"))
        modes = None
        if device_type is not None and device_type.profile == PROFILE_DRIVE:
            modes = reader.u32(c.SUPPORTED_DRIVE_MODES, 0, "supported drive modes", optional=True)
        identity = Identity(vendor, product, revision, serial) if vendor is not None else None
        return NodeReport(node_id, device_type=device_type, identity=identity, device_name=name,
                          hardware_version=hardware, software_version=software, modes=modes,
                          answered_sdo=answered, problems=tuple(reader.problems))
    finally:
        reader.close()


@dataclass
class ScanResult:
    reports: list[NodeReport] = field(default_factory=list)
    duration_s: float = 0.0


def scan_network(network: canopen.Network, settings: ScanSettings = ScanSettings()) -> ScanResult:
    """Listen for heartbeats, probe 0x1000 of every id, read each node that showed itself.
    Nodes are read one thread each (their SDO channels are independent)."""
    started = time.monotonic()
    watch = HeartbeatWatch(network, settings.node_ids)
    watch.start()
    try:
        time.sleep(settings.listen_s)
        probes = probe_device_types(network, settings.node_ids, settings)
        found = sorted(set(probes) | (watch.node_ids() & set(settings.node_ids)))
        reports: dict[int, NodeReport] = {}

        def read(node_id: int) -> None:
            try:
                if node_id in probes:
                    reports[node_id] = read_node(network, node_id, settings, probes[node_id])
                else:  # heard, but silent to the probe: not asked again
                    reports[node_id] = NodeReport(node_id)
            except Exception as err:  # noqa: BLE001 - listed with the reason, never dropped
                log.debug("scan read failed", exc_info=True)
                reports[node_id] = NodeReport(node_id, answered_sdo=node_id in probes,
                                              problems=(f"reading failed: {type(err).__name__}: {err}",))

        threads = [threading.Thread(target=read, args=(node_id,), name=f"scan-{node_id}") for node_id in found]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
    finally:
        watch.stop()
    result = [_with_heartbeat(reports[node_id], watch) for node_id in found if node_id in reports]
    duration = time.monotonic() - started
    log.info(kv("scan.done", nodes=[r.node_id for r in result], duration_s=round(duration, 3)))
    return ScanResult(result, duration)


def _with_heartbeat(report: NodeReport, watch: HeartbeatWatch) -> NodeReport:
    from dataclasses import replace

    return replace(report, nmt_state=watch.state(report.node_id), heartbeat_period_s=watch.period_s(report.node_id))


def open_network(interface: str, channel: str, bitrate: int) -> canopen.Network:
    """A connected canopen network on python-can (SocketCAN: its bitrate is the interface's,
    set with ``ip link``). OSError / can.CanError / ValueError when it cannot be opened."""
    if interface == "udp_multicast":
        raise ValueError("bus interface 'udp_multicast' is refused: its traffic leaves the machine")
    network = canopen.Network()
    if interface == "socketcan":
        network.connect(interface=interface, channel=channel)
    else:
        network.connect(interface=interface, channel=channel, bitrate=bitrate)
    return network
