"""Fault injections for simulated drives and their one-line text form.

Spec: comma-separated ``key=value`` pairs, e.g. ``node=2,kind=fault,at_sync=500,code=0x2310``.
Keys: node (required on the command line), kind (required), at_sync (the drive's SYNC index,
see recording), at_s (seconds after the simulation started; neither = at once), code, count,
index, subindex. Kinds:

- ``fault``: CiA-402 fault with EMCY ``code`` (default 0x1000), statusword fault bit;
- ``heartbeat_stop`` (alias ``power_loss``): the node goes silent completely;
- ``ignore_sync``: ignore the next ``count`` SYNCs (default: all from then on);
- ``following_error``: following-error fault at once (EMCY 0x8611, statusword bit 13);
- ``stall``: the motor stops following, so the following-error window trips by itself;
- ``drop_rpdo``: drop the next ``count`` RPDOs (default 1);
- ``sdo_abort``: refuse SDO writes to ``index``/``subindex`` (default: any) with abort ``code``
  (default 0x08000020), ``count`` times (default: always).
"""

from __future__ import annotations

from dataclasses import dataclass

from nurbsmotion.errors import InputError

KINDS = ("fault", "heartbeat_stop", "power_loss", "ignore_sync", "following_error", "stall", "drop_rpdo", "sdo_abort")
DEFAULT_FAULT_CODE = 0x1000
DEFAULT_SDO_ABORT_CODE = 0x0800_0020  # data cannot be transferred or stored
_INT_KEYS = ("node", "at_sync", "code", "count", "index", "subindex")


@dataclass(frozen=True)
class FaultInjection:
    """One fault to inject into a drive; triggered at ``at_sync``, at ``at_s`` or at once."""

    kind: str
    node_id: int | None = None
    at_sync: int | None = None
    at_s: float | None = None
    code: int | None = None
    count: int | None = None
    index: int | None = None
    subindex: int | None = None

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"unknown fault kind {self.kind!r} (one of {', '.join(KINDS)})")
        if self.at_sync is not None and self.at_s is not None:
            raise ValueError("give at_sync or at_s, not both")
        for name in ("at_sync", "count", "code", "index", "subindex"):
            value = getattr(self, name)
            if value is not None and value < 0:
                raise ValueError(f"{name} must be >= 0")
        if self.at_s is not None and self.at_s < 0:
            raise ValueError("at_s must be >= 0")

    @property
    def immediate(self) -> bool:
        return self.at_sync is None and self.at_s is None


def parse_fault_spec(text: str) -> FaultInjection:
    """Parse ``node=2,kind=fault,at_sync=500,code=0x2310``; InputError names the spec."""
    where = f"fault spec {text!r}"
    fields: dict[str, object] = {}
    for part in text.split(","):
        key, sep, value = part.strip().partition("=")
        key, value = key.strip(), value.strip()
        if not sep or not key or not value:
            raise InputError(where, f"expected key=value, got {part.strip()!r}")
        if key in fields:
            raise InputError(where, f"{key} given twice")
        try:
            if key in _INT_KEYS:
                fields[key] = int(value, 0)
            elif key == "at_s":
                fields[key] = float(value)
            elif key == "kind":
                fields[key] = value
            else:
                raise InputError(where, f"unknown key {key!r} (node, kind, at_sync, at_s, code, count, index, subindex)")
        except ValueError:
            raise InputError(where, f"{key}={value!r} is not a number") from None
    if "kind" not in fields:
        raise InputError(where, "kind is required")
    if "node" in fields:
        fields["node_id"] = fields.pop("node")
    try:
        return FaultInjection(**fields)  # type: ignore[arg-type]
    except ValueError as err:
        raise InputError(where, str(err)) from None
