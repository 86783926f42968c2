"""Machine configuration: YAML in, validated frozen records out, checked once at the edge.

Every error names the file, the YAML line and the field path, e.g.
``config/demo.yaml:14: axes[1].counts_per_mm: must be > 0, got -5``.
Unknown keys are errors too (a typo must not silently fall back to a default).
"""

from __future__ import annotations

import reprlib
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import yaml

from nurbsmotion.errors import InputError, InputErrors

if TYPE_CHECKING:  # the homing and io sections live in their own modules (they import this one)
    from nurbsmotion.homing_config import HomingConfig
    from nurbsmotion.io_config import IoConfig

ALGORITHMS = ("taylor1", "taylor2", "wang", "zhang", "lookahead")
AXIS_MODES = ("ip", "csp")


SYNC_SOURCES = ("auto", "loop", "kernel")


@dataclass(frozen=True)
class BusConfig:
    """``sync_source``: 'kernel' queues SYNC and RPDOs of the coming cycles in the SocketCAN
    broadcast manager (fieldbus.bcm_queue: a stall of the master shorter than the queue
    changes nothing on the wire; socketcan only); 'loop' sends them from the cycle thread at
    each deadline (a late thread delays the cycle); 'auto' (default): kernel on socketcan,
    loop on every other interface."""

    interface: str = "virtual"
    channel: str = "nurbsmotion"
    bitrate: int = 1_000_000
    sync_source: str = "auto"


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


@dataclass(frozen=True)
class IdentityConfig:
    vendor_id: int
    product_code: int


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
    eds: str | None = None
    identity: IdentityConfig | None = None


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


@dataclass(frozen=True)
class ControlConfig:
    socket: str = "/tmp/nurbsmotion.sock"
    group: str | None = None


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
    io: IoConfig | None = None
    simulate: bool = False
    lines: dict[str, int] = field(default_factory=dict, compare=False, repr=False)

    def axis_names(self) -> tuple[str, ...]:
        return tuple(a.name for a in self.axes)

    def where(self, path: str) -> str:
        """``file:line: path`` of a field, for errors found after loading (e.g. soft limits)."""
        line = self.lines.get(path)
        return f"{self.source}:{line}: {path}" if line else f"{self.source}: {path}"


# --------------------------------------------------------------------------------------
# YAML with line numbers


class _Doc:
    """A composed YAML node plus its field path; reads typed values with located errors."""

    def __init__(self, source: str, node: yaml.Node, path: str, errors: list[InputError], lines: dict[str, int]):
        self.source, self.node, self.path, self.errors, self.lines = source, node, path, errors, lines
        lines.setdefault(path, node.start_mark.line + 1)

    def where(self, node: yaml.Node | None = None, path: str | None = None) -> str:
        n = node or self.node
        return f"{self.source}:{n.start_mark.line + 1}: {path if path is not None else self.path}"

    def fail(self, message: str, node: yaml.Node | None = None, path: str | None = None) -> None:
        self.errors.append(InputError(self.where(node, path), message))

    def child_path(self, key: str | int) -> str:
        if isinstance(key, int):
            return f"{self.path}[{key}]"
        return f"{self.path}.{key}" if self.path else key

    def mapping(self, allowed: tuple[str, ...]) -> dict[str, "_Doc"]:
        if not isinstance(self.node, yaml.MappingNode):
            self.fail("must be a mapping of key: value")
            return {}
        out: dict[str, _Doc] = {}
        for key_node, value_node in self.node.value:
            key = key_node.value if isinstance(key_node, yaml.ScalarNode) else None
            if key not in allowed:
                self.fail(f"unknown key {key!r}; expected one of: {', '.join(allowed)}", key_node, self.child_path(str(key)))
            elif key in out:
                self.fail("duplicate key", key_node, self.child_path(key))
            else:
                out[key] = _Doc(self.source, value_node, self.child_path(key), self.errors, self.lines)
        return out

    def sequence(self) -> list["_Doc"]:
        if not isinstance(self.node, yaml.SequenceNode):
            self.fail("must be a list")
            return []
        return [_Doc(self.source, n, self.child_path(i), self.errors, self.lines) for i, n in enumerate(self.node.value)]

    def value(self) -> Any:
        try:
            return yaml.safe_load(yaml.serialize(self.node))
        except (yaml.YAMLError, ValueError, RecursionError) as err:  # '!!int 1.5', nested thousands deep
            self.fail(f"unreadable value ({' '.join(str(err).split())[:200]})")
            return None


_MISSING = object()
_SHOWN = reprlib.Repr()  # a value in an error message: short even for an alias bomb or a huge list
_SHOWN.maxlevel, _SHOWN.maxlist, _SHOWN.maxdict, _SHOWN.maxstring, _SHOWN.maxlong = 2, 4, 4, 60, 60


def _number(doc: _Doc, *, integer: bool = False, minimum: float | None = None, exclusive_min: bool = True,
            maximum: float | None = None) -> Any:
    value = doc.value()
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (integer and not isinstance(value, int)):
        doc.fail(f"must be {'an integer' if integer else 'a number'}, got {_SHOWN.repr(value)}")
        return _MISSING
    if not abs(value) <= sys.float_info.max:  # inf, nan, or an integer beyond the float range
        doc.fail(f"must be finite, got {_SHOWN.repr(value)}")
        return _MISSING
    if minimum is not None and (value <= minimum if exclusive_min else value < minimum):
        doc.fail(f"must be {'>' if exclusive_min else '>='} {minimum:g}, got {_SHOWN.repr(value)}")
        return _MISSING
    if maximum is not None and value > maximum:
        doc.fail(f"must be <= {maximum:g}, got {_SHOWN.repr(value)}")
        return _MISSING
    return value


def _string(doc: _Doc, choices: tuple[str, ...] | None = None) -> Any:
    value = doc.value()
    if not isinstance(value, str) or not value:
        doc.fail(f"must be a non-empty string, got {_SHOWN.repr(value)}")
        return _MISSING
    if choices is not None and value not in choices:
        doc.fail(f"must be one of {', '.join(choices)}, got {_SHOWN.repr(value)}")
        return _MISSING
    return value


def _boolean(doc: _Doc) -> Any:
    value = doc.value()
    if not isinstance(value, bool):
        doc.fail(f"must be true or false, got {_SHOWN.repr(value)}")
        return _MISSING
    return value


def _optional(reader: Callable[..., Any]) -> Callable[..., Any]:
    def read(doc: _Doc, **kw: Any) -> Any:
        return None if doc.value() is None else reader(doc, **kw)
    return read


def _section_reader(name: str) -> Callable[[_Doc], Any]:
    """The reader of the ``homing`` / ``io`` sections (their modules import this one)."""
    if name == "homing":
        from nurbsmotion.homing_config import read_homing
        return read_homing
    from nurbsmotion.io_config import read_io
    return read_io


def _fields(doc: _Doc, readers: dict[str, tuple[Callable[..., Any], dict[str, Any]]],
            required: tuple[str, ...] = ()) -> dict[str, Any]:
    """Read the keys of a mapping with their readers; collect errors; drop failed values."""
    found = doc.mapping(tuple(readers))
    for key in required:
        if key not in found:
            doc.fail(f"missing required key {key!r}")
    out: dict[str, Any] = {}
    for key, sub in found.items():
        reader, kw = readers[key]
        value = reader(sub, **kw)
        if value is not _MISSING:
            out[key] = value
    return out


def _limits_pair(doc: _Doc) -> Any:
    items = doc.sequence()
    if len(items) != 2:
        doc.fail("must be a list [min_mm, max_mm]")
        return _MISSING
    low, high = (_number(i) for i in items)
    if low is _MISSING or high is _MISSING:
        return _MISSING
    if not low < high:
        doc.fail(f"min must be < max, got [{low}, {high}]")
        return _MISSING
    return (float(low), float(high))


def _identity(doc: _Doc) -> Any:
    values = _fields(doc, {"vendor_id": (_number, {"integer": True, "minimum": 0, "exclusive_min": False}),
                           "product_code": (_number, {"integer": True, "minimum": 0, "exclusive_min": False})},
                     required=("vendor_id", "product_code"))
    return IdentityConfig(**values) if len(values) == 2 else _MISSING


_AXIS_READERS: dict[str, tuple[Callable[..., Any], dict[str, Any]]] = {
    "name": (_string, {}),
    "node_id": (_number, {"integer": True, "minimum": 1, "exclusive_min": False, "maximum": 127}),
    "mode": (_string, {"choices": AXIS_MODES}),
    "counts_per_mm": (_number, {"minimum": 0}),
    "invert": (_boolean, {}),
    "offset_counts": (_number, {"integer": True, "minimum": -(2**31), "exclusive_min": False, "maximum": 2**31 - 1}),
    "soft_limits_mm": (_optional(_limits_pair), {}),
    "max_velocity_mm_s": (_optional(_number), {"minimum": 0}),
    "homing": (_optional(lambda doc: _section_reader("homing")(doc)), {}),
    "max_accel_mm_s2": (_optional(_number), {"minimum": 0}),
    "following_error_window_mm": (_number, {"minimum": 0}),
    "following_error_timeout_ms": (_number, {"integer": True, "minimum": 0, "exclusive_min": False, "maximum": 65535}),
    "eds": (_optional(_string), {}),
    "identity": (_optional(_identity), {}),
}


def _axes(doc: _Doc) -> Any:
    axes = []
    items = doc.sequence()
    for item in items:
        values = _fields(item, _AXIS_READERS, required=("name", "node_id"))
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


def _section(cls: type, readers: dict[str, tuple[Callable[..., Any], dict[str, Any]]]) -> Callable[[_Doc], Any]:
    def read(doc: _Doc) -> Any:
        return cls(**_fields(doc, readers))
    return read


_POSITIVE: tuple[Callable[..., Any], dict[str, Any]] = (_number, {"minimum": 0})

_INTERPOLATION_READERS = {
    "algorithm": (_string, {"choices": ALGORITHMS}),
    "feed_mm_min": _POSITIVE,
    "rapid_feed_mm_min": _POSITIVE,
    "chord_error_mm": _POSITIVE,
    "max_accel_mm_s2": _POSITIVE,
    "max_jerk_mm_s3": (_optional(_number), {"minimum": 0}),
    "acc_time_s": _POSITIVE,
    "junction_deviation_mm": (_number, {"minimum": 0, "exclusive_min": False}),
}


def _interpolation(doc: _Doc) -> Any:
    values = _fields(doc, _INTERPOLATION_READERS)
    for per_min in ("feed_mm_min", "rapid_feed_mm_min"):
        if per_min in values:
            values[per_min.replace("_mm_min", "_mm_s")] = values.pop(per_min) / 60.0
    return InterpolationConfig(**values)


_TOP_READERS: dict[str, tuple[Callable[..., Any], dict[str, Any]]] = {
    "cycle_period_ms": (_number, {"minimum": 0.25, "exclusive_min": False, "maximum": 100}),
    "bus": (_section(BusConfig, {"interface": (_string, {}), "channel": (_string, {}),
                                 "sync_source": (_string, {"choices": SYNC_SOURCES}),
                                 "bitrate": (_number, {"integer": True, "minimum": 10_000, "exclusive_min": False,
                                                       "maximum": 1_000_000})}), {}),
    "interpolation": (_interpolation, {}),
    "axes": (_axes, {}),
    "io": (_optional(lambda doc: _section_reader("io")(doc)), {}),
    "monitoring": (_section(MonitoringConfig, {
        "heartbeat_producer_ms": (_number, {"integer": True, "minimum": 1, "exclusive_min": False, "maximum": 65535}),
        "heartbeat_consumer_ms": (_number, {"integer": True, "minimum": 1, "exclusive_min": False, "maximum": 65535}),
        "max_bus_load": (_number, {"minimum": 0, "maximum": 1}),
        "traffic_log": (_string, {"choices": TRAFFIC_LOG_FORMATS}),
        "feedback_log": (_boolean, {}),
    }), {}),
    "control": (_section(ControlConfig, {"socket": (_string, {}), "group": (_optional(_string), {})}), {}),
    "data_dir": (_string, {}),
    "simulate": (_boolean, {}),
}


def _check_cross_fields(cfg: MachineConfig, errors: list[InputError]) -> None:
    """Checks that involve more than one field; errors point at the field that must change."""
    def fail(path: str, message: str) -> None:
        errors.append(InputError(cfg.where(path), message))

    if cfg.bus.interface == "udp_multicast":
        fail("bus.interface", "bus interface 'udp_multicast' is refused: its traffic leaves the machine")
    if cfg.io is not None:
        from nurbsmotion.io_config import check_io_node
        check_io_node(cfg.io, tuple(a.node_id for a in cfg.axes), fail)
    mon = cfg.monitoring
    if mon.heartbeat_consumer_ms <= mon.heartbeat_producer_ms:
        fail("monitoring.heartbeat_consumer_ms", f"must be longer than heartbeat_producer_ms "
             f"({mon.heartbeat_consumer_ms} <= {mon.heartbeat_producer_ms})")


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
    doc = _Doc(source, root, "", errors, lines)
    values = _fields(doc, _TOP_READERS, required=("axes",))
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
        data_dir=values.get("data_dir", "var/nurbsmotion"),
        simulate=values.get("simulate", False),
        lines=lines,
    )
    _check_cross_fields(cfg, errors)
    if errors:
        raise InputErrors(errors)
    return _resolve_paths(cfg, base_dir)


def _resolve_paths(cfg: MachineConfig, base_dir: Path | None) -> MachineConfig:
    """Relative EDS paths are relative to the configuration file's folder."""
    if base_dir is None:
        return cfg
    from dataclasses import replace

    axes = tuple(replace(a, eds=str((base_dir / a.eds).resolve())) if a.eds and not Path(a.eds).is_absolute() else a
                 for a in cfg.axes)
    return replace(cfg, axes=axes)


def load_config(path: str | Path) -> MachineConfig:
    """Read and validate a configuration file."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise InputError(str(path), f"cannot read configuration: {getattr(err, 'strerror', None) or err}") from None
    return parse_config(text, source=str(path), base_dir=p.parent)
