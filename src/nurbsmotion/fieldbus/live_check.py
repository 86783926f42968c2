"""``nurbsmotion drives check --config FILE --live``: the running bus against the configuration.

Per configured node (each axis, the spindle, the io node), from a scan of the bus
(fieldbus.scan) plus reads of the PDO objects the bring-up plan maps:

- present: it answers SDO (a node heard only by its heartbeat cannot be checked);
- profile: 0x1000 bits 0-15 = 402 for axes and spindle, 401 for the io node;
- identity: 0x1018:01/02 = ``axes[].identity`` where configured (an error otherwise); against
  the EDS's [DeviceInfo] vendor/product where the file gives them (a warning: the EDS may
  describe a sibling product);
- modes: 0x6502 has the configured mode's bit (IP 6, CSP 7; spindle PV 2, CSV 8);
- PDO capacity: each PDO the plan maps exists (0x1400/0x1800 + n - 1, sub 1 readable) and its
  mapping object has as many entries as the plan puts in it (0x1600/0x1A00 + n - 1, sub k
  readable for k entries).

Nodes on the bus that the configuration does not name are warnings. Everything here only
reads (SDO upload): the bus may be checked with the drives powered, never while the daemon
runs (two SDO clients on one node's channel would take each other's answers).
"""

from __future__ import annotations

from dataclasses import dataclass

import canopen

from nurbsmotion.can import cia402 as c
from nurbsmotion.config import MachineConfig, axis_where
from nurbsmotion.fieldbus.bringup_plan import DrivePlan
from nurbsmotion.fieldbus.scan import PROFILE_DRIVE, PROFILE_IO, PROFILE_NAMES, NodeReport, ScanSettings, \
    SdoReader, supported_modes

AXIS_MODE_BITS = {"ip": (6, "ip"), "csp": (7, "csp")}
SPINDLE_MODE_BITS = {3: (2, "pv"), 9: (8, "csv")}


@dataclass(frozen=True)
class PdoNeed:
    """A PDO the bring-up maps: ``kind`` 'RPDO' / 'TPDO', number 1-4, entries mapped."""

    kind: str
    number: int
    entries: int

    @property
    def comm_index(self) -> int:
        return (c.RPDO_COMM if self.kind == "RPDO" else c.TPDO_COMM) + self.number - 1

    @property
    def mapping_index(self) -> int:
        return (c.RPDO_MAPPING if self.kind == "RPDO" else c.TPDO_MAPPING) + self.number - 1


@dataclass(frozen=True)
class ExpectedNode:
    node_id: int
    where: str  # ``m.yaml:12: axes[0] (X, node 1)``: the place every finding names
    profile: int
    identity: tuple[int, int] | None = None  # configured: must match
    eds_identity: tuple[int, int] | None = None  # the EDS's [DeviceInfo]: should match
    eds_name: str = ""
    mode_bit: tuple[int, str] | None = None
    pdos: tuple[PdoNeed, ...] = ()


@dataclass(frozen=True)
class Finding:
    error: bool  # False: a warning (printed, exit code unchanged)
    text: str


def _device_identity(od: object) -> tuple[int, int] | None:
    info = getattr(od, "device_information", None)
    vendor, product = getattr(info, "vendor_number", None), getattr(info, "product_number", None)
    return (vendor, product) if vendor is not None and product is not None and (vendor or product) else None


def expected_nodes(config: MachineConfig, plans: list[DrivePlan]) -> list[ExpectedNode]:
    """What the configuration (and the bring-up plans of its axes) expects on the bus."""
    out = []
    for plan in plans:
        axis = config.axes[plan.axis_index]
        frames = plan.layout.rpdos + plan.layout.tpdos
        out.append(ExpectedNode(
            axis.node_id, axis_where(config, plan.axis_index), PROFILE_DRIVE,
            (axis.identity.vendor_id, axis.identity.product_code) if axis.identity else None,
            _device_identity(axis.od), plan.eds, AXIS_MODE_BITS[axis.mode],
            tuple(PdoNeed(f.kind, f.number, len(f.fields)) for f in frames)))
    spindle = config.spindle
    if spindle is not None and not isinstance(spindle, str):
        out.append(ExpectedNode(spindle.node_id, f"{config.where('spindle')} (node {spindle.node_id})",
                                PROFILE_DRIVE, mode_bit=SPINDLE_MODE_BITS.get(spindle.mode.number)))
    if config.io is not None:
        out.append(ExpectedNode(config.io.node_id, f"{config.where('io')} (node {config.io.node_id})", PROFILE_IO))
    return out


def compare(expected: ExpectedNode, report: NodeReport | None) -> list[Finding]:
    """The findings about one configured node (pure)."""
    where = expected.where
    if report is None:
        return [Finding(True, f"{where}: not on the bus (no heartbeat, no SDO answer to 0x1000)")]
    if not report.answered_sdo:
        return [Finding(True, f"{where}: heard by its heartbeat only ({report.status()}): cannot be checked")]
    findings = [Finding(True, f"{where}: {problem}") for problem in report.problems]
    if report.profile is not None and report.profile != expected.profile:
        findings.append(Finding(True, f"{where}: device type 0x{report.device_type.raw:08X} is "  # type: ignore[union-attr]
                                      f"{report.device_type.describe()}, expected {PROFILE_NAMES[expected.profile]}"))  # type: ignore[union-attr]
    findings += _identity_findings(expected, report)
    if expected.mode_bit is not None and report.modes is not None and not report.modes >> expected.mode_bit[0] & 1:
        findings.append(Finding(True, f"{where}: 0x6502 = 0x{report.modes:08X} ({' '.join(supported_modes(report.modes))}) "
                                      f"has no {expected.mode_bit[1]} (bit {expected.mode_bit[0]})"))
    elif expected.mode_bit is not None and report.modes is None and report.profile == PROFILE_DRIVE:
        findings.append(Finding(False, f"{where}: 0x6502 not readable: the mode is checked at bring-up "
                                       "(0x6061 read back)"))
    return findings


def _identity_findings(expected: ExpectedNode, report: NodeReport) -> list[Finding]:
    ident = report.identity
    if ident is None or ident.product_code is None:
        return []
    found = (ident.vendor_id, ident.product_code)
    said = f"vendor {ident.vendor()} product 0x{ident.product_code:08X}"
    if expected.identity is not None and found != expected.identity:
        return [Finding(True, f"{expected.where}: the node reports {said}, identity says vendor "
                              f"0x{expected.identity[0]:08X} product 0x{expected.identity[1]:08X}")]
    if expected.eds_identity is not None and found != expected.eds_identity:
        return [Finding(False, f"{expected.where}: the node reports {said}, {expected.eds_name} describes vendor "
                               f"0x{expected.eds_identity[0]:08X} product 0x{expected.eds_identity[1]:08X}")]
    return []


def extra_nodes(expected: list[ExpectedNode], reports: list[NodeReport], master_node_id: int) -> list[Finding]:
    """Nodes on the bus the configuration does not name (warnings)."""
    named = {e.node_id for e in expected} | {master_node_id}
    return [Finding(False, f"node {r.node_id} "
                           f"({r.device_type.describe() if r.device_type else r.status()}) is on the bus but not "
                           "in the configuration") for r in reports if r.node_id not in named]


def read_pdo_capacity(network: canopen.Network, node_id: int, pdos: tuple[PdoNeed, ...], where: str,
                      settings: ScanSettings) -> list[Finding]:
    """Each planned PDO exists and its mapping object holds its entries (SDO reads)."""
    reader = SdoReader(network, node_id, settings.sdo_timeout_s)
    try:
        for need in pdos:
            name = f"{need.kind}{need.number}"
            reader.raw(need.comm_index, 1, f"{name} COB-ID", optional=False)
            reader.raw(need.mapping_index, need.entries, f"{name} mapping entry {need.entries}", optional=False)
    finally:
        reader.close()
    return [Finding(True, f"{where}: PDO capacity: {problem}") for problem in reader.problems]
