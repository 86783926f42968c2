"""Machine configuration: YAML in, validated frozen records out, checked once at the edge.

Every error names the file, the YAML line and the field path, e.g.
``config/demo.yaml:14: axes[1].counts_per_mm: must be > 0, got -5``.
Unknown keys are errors too (a typo must not silently fall back to a default).

This module reads the machine's top level (bus, axes, monitoring, control, web, notify ...)
and composes the sections that have their own modules: ``yaml_reading`` (the readers every
section uses), ``homing`` (``axes[i].homing``, ``axes[i].sim``), ``io`` (the I/O node),
``spindle`` (the spindle drive) and ``tooling`` (``tools:``, ``spindle: none``).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import yaml

from nurbsmotion.can import drive_od
from nurbsmotion.config.yaml_reading import MISSING, Doc, boolean, fields, number, optional, sequence_of, string
from nurbsmotion.can.drive_od import default_eds_path
from nurbsmotion.errors import InputError, InputErrors
from nurbsmotion.config.homing import AxisSimSensors, HomingConfig, read_axis_sim, read_homing
from nurbsmotion.config.io import IoConfig, check_io_limits, check_io_node, read_io
from nurbsmotion.service.protocol import DEFAULT_SOCKET
from nurbsmotion.config.spindle import SpindleConfig, load_spindle_description
from nurbsmotion.config.tooling import load_tool_file, read_spindle, read_tools

if TYPE_CHECKING:  # read when a configuration names a tool table (config.tooling.load_tool_file)
    from canopen.objectdictionary import ObjectDictionary

    from nurbsmotion.program.tools import ToolTable

ALGORITHMS = ("taylor1", "taylor2", "wang", "zhang", "lookahead")
AXIS_MODES = ("ip", "csp")


SYNC_SOURCES = ("auto", "loop", "kernel")


@dataclass(frozen=True)
class BusConfig:
    """``sync_source``: 'kernel' queues SYNC and RPDOs of the coming cycles in the SocketCAN
    broadcast manager (fieldbus.bcm_queue: a stall of the master shorter than the queue
    changes nothing on the wire; socketcan only); 'loop' sends them from the cycle thread at
    each deadline (a late thread delays the cycle); 'auto' (default): kernel on socketcan,
    loop on every other interface. ``sync_window_us``: 0x1007 on the drives (RPDOs later
    than this after SYNC are discarded); 0 = no window, the default (the kernel queue sends
    the last RPDO T/(1 + n) before the next SYNC, the loop may be preempted between them)."""

    interface: str = "virtual"
    channel: str = "nurbsmotion"
    bitrate: int = 1_000_000
    sync_source: str = "auto"
    sync_window_us: int = 0  # 0x1007 written on every drive that has it; 0 = no window
    # CiA-402 bring-up: how long a drive may take to answer one state-machine step (a real
    # drive: milliseconds); drives emulated by processes inside User-Mode Linux need seconds
    drive_step_timeout_ms: int = 500
    sdo_timeout_ms: int = 500  # an SDO answer (CiA 301 client time-out) from any node


@dataclass(frozen=True)
class InterpolationConfig:
    """Planning defaults; a program's F and CLI options override feed and algorithm."""

    algorithm: str = "lookahead"
    feed_mm_s: float = 200.0
    rapid_feed_mm_s: float = 200.0
    chord_error_mm: float = 0.01
    max_accel_mm_s2: float = 2500.0
    max_jerk_mm_s3: float | None = 50_000.0
    acc_time_s: float = 1.2
    junction_deviation_mm: float = 0.01
    path_tolerance_mm: float = 0.01  # corner blends stay this close to the programmed path (G64 P overrides)
    smoothing: bool = True  # short-segment runs merged and fitted within the path tolerance (G64 Q overrides)


@dataclass(frozen=True)
class IdentityConfig:
    vendor_id: int
    product_code: int


@dataclass(frozen=True)
class SdoEntry:
    """One vendor object written after the standard bring-up (``axes[].sdo``), checked
    against the axis' EDS at load time. ``type`` (int8 ... uint32), when given, must be the
    EDS's data type. ``where`` is ``file:line: axes[i].sdo[j]`` for later messages."""

    index: int
    subindex: int
    value: int
    type: str | None = None
    where: str = field(default="", compare=False)


@dataclass(frozen=True)
class AxisConfig:
    name: str
    node_id: int
    mode: str = "csp"
    counts_per_mm: float = 1000.0
    invert: bool = False
    offset_counts: int = 0
    soft_limits_mm: tuple[float, float] | None = None
    max_velocity_mm_s: float | None = None
    homing: HomingConfig | None = None
    max_accel_mm_s2: float | None = None
    following_error_window_mm: float = 1.0
    following_error_timeout_ms: int = 20
    eds: str | None = None  # after loading: the file read (the packaged EDS when not given)
    identity: IdentityConfig | None = None
    quick_stop_decel: int | None = None  # 0x6085 in the drive's own units; None: left to the drive
    sdo: tuple[SdoEntry, ...] = ()
    od: ObjectDictionary | None = field(default=None, compare=False, repr=False)  # the EDS as canopen reads it
    sim: AxisSimSensors | None = None  # the simulated drive's switches and index pulses (config.homing)


TRAFFIC_LOG_FORMATS = ("none", "log", "asc")


@dataclass(frozen=True)
class MonitoringConfig:
    """``traffic_log``: each job's folder gets every bus frame of the job as ``traffic.log``
    (candump) or ``traffic.asc`` (Vector ASCII); 'none' records nothing. ``feedback_log``:
    each job's folder gets ``feedback.csv``, every TPDO1 (statusword, position actual)."""

    heartbeat_producer_ms: int = 100
    heartbeat_consumer_ms: int = 300
    max_bus_load: float = 0.8
    traffic_log: str = "none"
    feedback_log: bool = True
    master_heartbeat_ms: int = 100  # the master's own heartbeat period; 0 = none (and no 0x1016 written)
    master_heartbeat_consumer_multiple: int = 5  # each drive's 0x1016 time = this x master_heartbeat_ms


@dataclass(frozen=True)
class MasterConfig:
    """The master is a CANopen node too: its heartbeat carries ``node_id`` (CiA 301)."""

    node_id: int = 127


@dataclass(frozen=True)
class ControlConfig:
    socket: str = DEFAULT_SOCKET
    group: str | None = None


SAFE_Z_MARGIN_MM = 1.0  # machine.safe_z_mm's default: this far below Z's upper soft limit


@dataclass(frozen=True)
class MachineSettings:
    """The ``machine:`` section: settings of the machine as a whole (not of one axis or device).

    ``safe_z_mm``: machine Z (mm) the approach to a program's start line rises to before it
    moves in X/Y (program.gcode_start); default: Z's upper soft limit minus SAFE_Z_MARGIN_MM."""

    safe_z_mm: float | None = None


class GatewayCpus(Enum):
    """``web.cpus`` as a word (web.priority); else a list of CPU numbers."""

    AUTO = "auto"  # every CPU the gateway may use but the daemon's real-time one (runtime.realtime_cpu)
    ALL = "all"  # where it was started


@dataclass(frozen=True)
class WebConfig:
    """``nurbsmotion web``: where the gateway listens and who may use it (docs/web.md)."""

    host: str = "127.0.0.1"
    port: int = 8080
    require_auth: bool = False  # on loopback; any other address always requires keys
    max_upload_mb: float = 64.0
    cors_origins: tuple[str, ...] = ()
    nice: int = 10  # added to the gateway's niceness at start-up: it never competes with the daemon
    cpus: GatewayCpus | tuple[int, ...] = GatewayCpus.AUTO  # where its threads run (web.priority)


def parse_listen(text: str) -> tuple[str, int]:
    """``HOST:PORT`` (``[::1]:8080`` for IPv6) -> (host, port); ValueError names what is wrong."""
    host, sep, port = text.rpartition(":")
    host = host[1:-1] if host.startswith("[") and host.endswith("]") else host
    if not sep or not host or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ValueError(f"must be HOST:PORT with a port 1-65535, e.g. 127.0.0.1:8080, got {text!r}")
    return host, int(port)


def _listen(doc: Doc) -> Any:
    value = string(doc)
    if value is MISSING:
        return value
    try:
        return parse_listen(value)
    except ValueError as err:
        doc.fail(str(err))
        return MISSING


def _origins(doc: Doc) -> Any:
    items = doc.sequence()
    origins = tuple(string(item) for item in items)
    return MISSING if MISSING in origins else origins


def _cpus(doc: Doc) -> Any:
    """``auto``, ``all`` or a non-empty list of CPU numbers (checked against the machine when
    the gateway starts: web.priority)."""
    if not isinstance(doc.node, yaml.SequenceNode):
        word = string(doc, choices=tuple(c.value for c in GatewayCpus))
        return MISSING if word is MISSING else GatewayCpus(word)
    numbers = sequence_of(lambda item: number(item, integer=True, minimum=0, exclusive_min=False))(doc)
    if numbers == ():
        doc.fail("must list at least one CPU (or be auto or all)")
        return MISSING
    return numbers if numbers is MISSING else tuple(sorted(set(numbers)))


def _web(doc: Doc) -> Any:
    found = fields(doc, {"listen": (_listen, {}), "require_auth": (boolean, {}),
                          "max_upload_mb": (number, {"minimum": 0}), "cors_origins": (_origins, {}),
                          "nice": (number, {"integer": True, "minimum": 0, "exclusive_min": False, "maximum": 19}),
                          "cpus": (_cpus, {})})
    host, port = found.pop("listen", (WebConfig.host, WebConfig.port))
    return WebConfig(host=host, port=port, **found)


NOTIFIED_EVENTS = ("job_ended", "fault")  # the daemon's log events a webhook can be sent for


@dataclass(frozen=True)
class NotifyConfig:
    """``notify:``: webhooks POSTed at job ends and faults (service.webhooks)."""

    webhooks: tuple[str, ...] = ()
    events: tuple[str, ...] = NOTIFIED_EVENTS
    timeout_s: float = 5.0
    attempts: int = 5
    retry_s: float = 2.0


def _url(doc: Doc) -> Any:
    value = string(doc)
    if value is MISSING:
        return value
    scheme, sep, rest = value.partition("://")
    if scheme not in ("http", "https") or not sep or not rest.split("/")[0]:
        doc.fail(f"must be an http:// or https:// URL with a host, got {value!r}")
        return MISSING
    return value


def _events(doc: Doc) -> Any:
    names = tuple(string(item, choices=NOTIFIED_EVENTS) for item in doc.sequence())
    return MISSING if MISSING in names else names


def _notify(doc: Doc) -> Any:
    found = fields(doc, {"webhooks": (sequence_of(_url), {}), "events": (_events, {}),
                          "timeout_s": (number, {"minimum": 0}), "attempts": (number, {"integer": True, "minimum": 0}),
                          "retry_s": (number, {"minimum": 0})})
    return NotifyConfig(**found)


@dataclass(frozen=True)
class MachineConfig:
    source: str
    cycle_period_s: float
    bus: BusConfig
    interpolation: InterpolationConfig
    axes: tuple[AxisConfig, ...]
    monitoring: MonitoringConfig
    control: ControlConfig
    data_dir: str
    web: WebConfig = WebConfig()
    notify: NotifyConfig = NotifyConfig()
    io: IoConfig | None = None
    simulate: bool = False
    master: MasterConfig = MasterConfig()
    tools: str | None = None  # tool table file (config.tooling); tool_table: its contents
    tool_table: ToolTable | None = field(default=None, compare=False, repr=False)
    spindle: SpindleConfig | str | None = None  # 'none' or absent (None): no spindle drive
    require_homing: bool | None = None  # None: required on socketcan without simulate (service.homing)
    machine: MachineSettings = MachineSettings()
    lines: dict[str, int] = field(default_factory=dict, compare=False, repr=False)

    def axis_names(self) -> tuple[str, ...]:
        return tuple(a.name for a in self.axes)

    def where(self, path: str) -> str:
        """``file:line: path`` of a field, for errors found after loading (e.g. soft limits)."""
        line = self.lines.get(path)
        return f"{self.source}:{line}: {path}" if line else f"{self.source}: {path}"

    def safe_z_mm(self) -> float | None:
        """Where a start-line approach rises to: ``machine.safe_z_mm``, else Z's upper soft limit
        minus SAFE_Z_MARGIN_MM; None on a machine without a Z axis (no rise). InputError naming
        machine.safe_z_mm when neither is configured."""
        if self.machine.safe_z_mm is not None:
            return self.machine.safe_z_mm
        z = next((a for a in self.axes if a.name == "Z"), None)
        if z is None:
            return None
        if z.soft_limits_mm is None:
            raise InputError(self.where("machine.safe_z_mm"), "not set, and axis Z has no soft_limits_mm to take it "
                                                              "from: set it to start a program from a line")
        return z.soft_limits_mm[1] - SAFE_Z_MARGIN_MM


# --------------------------------------------------------------------------------------
# YAML with line numbers


def _limits_pair(doc: Doc) -> Any:
    items = doc.sequence() if isinstance(doc.node, yaml.SequenceNode) else []  # one error for a non-list
    if len(items) != 2:
        doc.fail("must be a list [min_mm, max_mm]")
        return MISSING
    low, high = (number(i) for i in items)
    if low is MISSING or high is MISSING:
        return MISSING
    if not low < high:
        doc.fail(f"min must be < max, got [{low}, {high}]")
        return MISSING
    return (float(low), float(high))


def _identity(doc: Doc) -> Any:
    values = fields(doc, {"vendor_id": (number, {"integer": True, "minimum": 0, "exclusive_min": False}),
                           "product_code": (number, {"integer": True, "minimum": 0, "exclusive_min": False})},
                     required=("vendor_id", "product_code"))
    return IdentityConfig(**values) if len(values) == 2 else MISSING


def _sdo_entry(doc: Doc) -> Any:
    values = fields(doc, {"index": (number, {"integer": True, "minimum": 0x1000, "exclusive_min": False,
                                               "maximum": 0xFFFF}),
                           "subindex": (number, {"integer": True, "minimum": 0, "exclusive_min": False,
                                                  "maximum": 255}),
                           "value": (number, {"integer": True, "minimum": -(2**63), "exclusive_min": False,
                                               "maximum": 2**64 - 1}),
                           "type": (string, {"choices": tuple(drive_od.TYPE_CODES)})},
                     required=("index", "value"))
    if "index" not in values or "value" not in values:
        return MISSING
    return SdoEntry(values["index"], values.get("subindex", 0), values["value"], values.get("type"), doc.where())


def _sdo_list(doc: Doc) -> Any:
    entries = [_sdo_entry(item) for item in doc.sequence()]
    return tuple(e for e in entries if e is not MISSING)


_AXIS_READERS: dict[str, tuple[Callable[..., Any], dict[str, Any]]] = {
    "name": (string, {}),
    "node_id": (number, {"integer": True, "minimum": 1, "exclusive_min": False, "maximum": 127}),
    "mode": (string, {"choices": AXIS_MODES}),
    "counts_per_mm": (number, {"minimum": 0}),
    "invert": (boolean, {}),
    "offset_counts": (number, {"integer": True, "minimum": -(2**31), "exclusive_min": False, "maximum": 2**31 - 1}),
    "soft_limits_mm": (optional(_limits_pair), {}),
    "max_velocity_mm_s": (optional(number), {"minimum": 0}),
    "homing": (optional(read_homing), {}),
    "max_accel_mm_s2": (optional(number), {"minimum": 0}),
    "following_error_window_mm": (number, {"minimum": 0}),
    "following_error_timeout_ms": (number, {"integer": True, "minimum": 0, "exclusive_min": False, "maximum": 65535}),
    "eds": (optional(string), {}),
    "identity": (optional(_identity), {}),
    "quick_stop_decel": (optional(number), {"integer": True, "minimum": 0, "maximum": 2**32 - 1}),
    "sdo": (_sdo_list, {}),
    "sim": (optional(read_axis_sim), {}),
}


def _axes(doc: Doc) -> Any:
    axes = []
    items = doc.sequence()
    for item in items:
        values = fields(item, _AXIS_READERS, required=("name", "node_id"))
        if "name" in values and "node_id" in values:
            axes.append((item, AxisConfig(**values)))
    if isinstance(doc.node, yaml.SequenceNode) and not items:
        doc.fail("needs at least one axis")
    seen_names: dict[str, int] = {}
    seen_nodes: dict[int, int] = {}
    for item, axis in axes:
        if axis.name in seen_names:
            item.fail(f"axis name {axis.name!r} is used twice", path=item.child_path("name"))
        if axis.node_id in seen_nodes:
            item.fail(f"node id {axis.node_id} is used twice", path=item.child_path("node_id"))
        seen_names[axis.name] = seen_nodes[axis.node_id] = 1
    if len(axes) > 6:
        doc.fail(f"at most 6 axes are supported, got {len(axes)}")
    return tuple(a for _, a in axes)


def _section(cls: type, readers: dict[str, tuple[Callable[..., Any], dict[str, Any]]]) -> Callable[[Doc], Any]:
    def read(doc: Doc) -> Any:
        return cls(**fields(doc, readers))
    return read


_POSITIVE: tuple[Callable[..., Any], dict[str, Any]] = (number, {"minimum": 0})

_INTERPOLATION_READERS: dict[str, tuple[Callable[..., Any], dict[str, Any]]] = {
    "algorithm": (string, {"choices": ALGORITHMS}),
    "feed_mm_min": _POSITIVE,
    "rapid_feed_mm_min": _POSITIVE,
    "chord_error_mm": _POSITIVE,
    "max_accel_mm_s2": _POSITIVE,
    "max_jerk_mm_s3": (optional(number), {"minimum": 0}),
    "acc_time_s": _POSITIVE,
    "junction_deviation_mm": (number, {"minimum": 0, "exclusive_min": False}),
    "path_tolerance_mm": (number, {"minimum": 0, "exclusive_min": False}),
    "smoothing": (boolean, {}),
}


def _interpolation(doc: Doc) -> Any:
    values = fields(doc, _INTERPOLATION_READERS)
    for per_min in ("feed_mm_min", "rapid_feed_mm_min"):
        if per_min in values:
            values[per_min.replace("_mm_min", "_mm_s")] = values.pop(per_min) / 60.0
    return InterpolationConfig(**values)


_TOP_READERS: dict[str, tuple[Callable[..., Any], dict[str, Any]]] = {
    "cycle_period_ms": (number, {"minimum": 0.25, "exclusive_min": False, "maximum": 100}),
    "bus": (_section(BusConfig, {"interface": (string, {}), "channel": (string, {}),
                                 "sync_source": (string, {"choices": SYNC_SOURCES}),
                                 "sync_window_us": (number, {"integer": True, "minimum": 0, "exclusive_min": False,
                                                              "maximum": 2**32 - 1}),
                                 "bitrate": (number, {"integer": True, "minimum": 10_000, "exclusive_min": False,
                                                       "maximum": 1_000_000}),
                                 "drive_step_timeout_ms": (number, {"integer": True, "minimum": 10,
                                                                     "exclusive_min": False, "maximum": 60_000}),
                                 "sdo_timeout_ms": (number, {"integer": True, "minimum": 10,
                                                              "exclusive_min": False, "maximum": 60_000})}), {}),
    "interpolation": (_interpolation, {}),
    "axes": (_axes, {}),
    "io": (optional(read_io), {}),
    "monitoring": (_section(MonitoringConfig, {
        "heartbeat_producer_ms": (number, {"integer": True, "minimum": 1, "exclusive_min": False, "maximum": 65535}),
        "heartbeat_consumer_ms": (number, {"integer": True, "minimum": 1, "exclusive_min": False, "maximum": 65535}),
        "max_bus_load": (number, {"minimum": 0, "maximum": 1}),
        "traffic_log": (string, {"choices": TRAFFIC_LOG_FORMATS}),
        "feedback_log": (boolean, {}),
        "master_heartbeat_ms": (number, {"integer": True, "minimum": 0, "exclusive_min": False, "maximum": 65535}),
        "master_heartbeat_consumer_multiple": (number, {"integer": True, "minimum": 3, "exclusive_min": False,
                                                         "maximum": 100}),
    }), {}),
    "master": (_section(MasterConfig, {"node_id": (number, {"integer": True, "minimum": 1, "exclusive_min": False,
                                                             "maximum": 127})}), {}),
    "control": (_section(ControlConfig, {"socket": (string, {}), "group": (optional(string), {})}), {}),
    "data_dir": (string, {}),
    "web": (_web, {}),
    "notify": (_notify, {}),
    "simulate": (boolean, {}),
    "require_homing": (boolean, {}),
    "machine": (_section(MachineSettings, {"safe_z_mm": (number, {})}), {}),
    "tools": (optional(read_tools), {}),
    "spindle": (optional(read_spindle), {}),
}


def _check_cross_fields(cfg: MachineConfig, errors: list[InputError]) -> None:
    """Checks that involve more than one field; errors point at the field that must change."""
    def fail(path: str, message: str) -> None:
        errors.append(InputError(cfg.where(path), message))

    if cfg.bus.interface == "udp_multicast":
        fail("bus.interface", "bus interface 'udp_multicast' is refused: its traffic leaves the machine")
    if cfg.io is not None:
        check_io_node(cfg.io, tuple(a.node_id for a in cfg.axes), fail)
        check_io_limits(cfg.io, cfg.axis_names(), fail)
    mon = cfg.monitoring
    if mon.heartbeat_consumer_ms <= mon.heartbeat_producer_ms:
        fail("monitoring.heartbeat_consumer_ms", f"must be longer than heartbeat_producer_ms "
             f"({mon.heartbeat_consumer_ms} <= {mon.heartbeat_producer_ms})")
    consumer_ms = mon.master_heartbeat_ms * mon.master_heartbeat_consumer_multiple
    if consumer_ms > 0xFFFF:
        multiple = "monitoring.master_heartbeat_consumer_multiple"
        fail(multiple if multiple in cfg.lines else "monitoring.master_heartbeat_ms", f"the drives' consumer time {consumer_ms} ms "
             f"(master_heartbeat_ms x multiple) does not fit 0x1016 (at most 65535 ms)")
    if cfg.io is not None and cfg.io.node_id == cfg.master.node_id:
        fail("io.node_id", f"node id {cfg.io.node_id} is the master's (master.node_id)")
    for i, axis in enumerate(cfg.axes):
        if axis.node_id == cfg.master.node_id:
            fail(f"axes[{i}].node_id", f"node id {axis.node_id} is the master's (master.node_id)")
    safe_z = cfg.machine.safe_z_mm
    z_limits = next((a.soft_limits_mm for a in cfg.axes if a.name == "Z"), None)
    if safe_z is not None and z_limits is not None and not z_limits[0] <= safe_z <= z_limits[1]:
        fail("machine.safe_z_mm", f"{safe_z:g} mm is outside axis Z's soft limits [{z_limits[0]:g}, {z_limits[1]:g}] mm")


def parse_config(text: str, source: str = "<config>", base_dir: Path | None = None) -> MachineConfig:
    """Parse and validate a YAML configuration; raise InputErrors listing every problem."""
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.MarkedYAMLError as err:
        line = err.problem_mark.line + 1 if err.problem_mark else 0
        raise InputError(f"{source}:{line}", f"not valid YAML: {err.problem}") from None
    except yaml.YAMLError as err:
        raise InputError(source, f"not valid YAML: {' '.join(str(err).split())}") from None
    except RecursionError:
        raise InputError(source, "not valid YAML: nested too deeply") from None
    if root is None:
        raise InputError(source, "empty configuration")
    errors: list[InputError] = []
    lines: dict[str, int] = {}
    doc = Doc(source, root, "", errors, lines)
    values = fields(doc, _TOP_READERS, required=("axes",))
    if errors:
        raise InputErrors(errors)
    period_ms = values.pop("cycle_period_ms", 4.0)
    cfg = MachineConfig(
        source=source,
        cycle_period_s=period_ms / 1000.0,
        bus=values.get("bus", BusConfig()),
        interpolation=values.get("interpolation", InterpolationConfig()),
        axes=values["axes"],
        io=values.get("io"),
        monitoring=values.get("monitoring", MonitoringConfig()),
        control=values.get("control", ControlConfig()),
        web=values.get("web", WebConfig()),
        notify=values.get("notify", NotifyConfig()),
        data_dir=values.get("data_dir", "var/nurbsmotion"),
        simulate=values.get("simulate", False),
        master=values.get("master", MasterConfig()),
        tools=values.get("tools"),
        spindle=values.get("spindle"),
        require_homing=values.get("require_homing"),
        machine=values.get("machine", MachineSettings()),
        lines=lines,
    )
    _check_cross_fields(cfg, errors)
    if errors:
        raise InputErrors(errors)
    cfg = _with_descriptions(cfg, base_dir, errors)
    if errors:
        raise InputErrors(errors)
    if cfg.tools is not None:
        tools, table = load_tool_file(cfg.tools, cfg.where("tools"), base_dir)
        cfg = replace(cfg, tools=tools, tool_table=table)
    if isinstance(cfg.spindle, SpindleConfig):
        cfg = replace(cfg, spindle=load_spindle_description(cfg.spindle, _node_users(cfg), cfg.where, base_dir))
    return cfg


def _node_users(cfg: MachineConfig) -> dict[int, str]:
    """Who uses each node id besides the spindle: the axes and the io node."""
    used = {a.node_id: f"axis {a.name}" for a in cfg.axes}
    if cfg.io is not None:
        used[cfg.io.node_id] = "the io node"
    return used


def axis_where(cfg: MachineConfig, i: int, field_name: str = "") -> str:
    """``file:line: axes[i][.field] (X, node 1)``: the place named by drive-related errors."""
    axis = cfg.axes[i]
    path = f"axes[{i}].{field_name}" if field_name and f"axes[{i}].{field_name}" in cfg.lines else f"axes[{i}]"
    return f"{cfg.where(path)} ({axis.name}, node {axis.node_id})"


def _with_descriptions(cfg: MachineConfig, base_dir: Path | None, errors: list[InputError]) -> MachineConfig:
    """Read each axis' EDS/DCF (relative to the configuration's folder; the packaged one when
    not given) with canopen's import_od, and check its ``sdo:`` list against it."""
    axes = []
    for i, axis in enumerate(cfg.axes):
        path = Path(axis.eds) if axis.eds else Path(default_eds_path())
        if axis.eds and base_dir is not None and not path.is_absolute():
            path = (base_dir / path).resolve()
        try:
            od = drive_od.load_description(path, axis.node_id)
        except drive_od.DescriptionError as err:
            errors.append(InputError(axis_where(cfg, i, "eds"), str(err)))
            axes.append(axis)
            continue
        for entry in axis.sdo:
            problem = _sdo_problem(od, entry)
            if problem:
                joint = " " if problem.startswith("has no") else ": "
                errors.append(InputError(f"{entry.where} ({axis.name}, node {axis.node_id})",
                                         f"{path.name}{joint}{problem}"))
        axes.append(replace(axis, eds=str(path), od=od))
    return replace(cfg, axes=tuple(axes))


def _sdo_problem(od: ObjectDictionary, entry: SdoEntry) -> str | None:
    """Why the drive described by ``od`` would refuse this write (missing, read-only, range)."""
    where = drive_od.name_of(entry.index, entry.subindex)
    var = drive_od.find(od, entry.index, entry.subindex)
    if var is None:
        return f"has no {where}" if entry.index not in od.indices else f"{where}: 0x{entry.index:04X} has no " \
            f"sub-index {entry.subindex}"
    if entry.type is not None and drive_od.TYPE_CODES[entry.type] != var.data_type:
        return f"{where} ({var.name}) is {drive_od.type_name(var)}, not {entry.type}"
    problem = drive_od.write_problem(var, entry.value)
    return f"{where} ({var.name}) {problem}" if problem else None


def load_config(path: str | Path) -> MachineConfig:
    """Read and validate a configuration file."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as err:
        raise InputError(str(path), f"cannot read configuration: {getattr(err, 'strerror', None) or err}") from None
    return parse_config(text, source=str(path), base_dir=p.parent)
