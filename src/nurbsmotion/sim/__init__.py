"""Simulated CiA-402 servo drives (IP, CSP, homing; PV and CSV for a spindle) and a CiA-401
I/O node on any python-can bus, with set-point recording and fault injection. Never imports nurbsmotion.fieldbus: the drive side is an independent
implementation of CiA 301/402 against which the master is tested.
"""

from nurbsmotion.sim.axis import AxisParameters, Cia402Axis
from nurbsmotion.sim.drive import SimDrive
from nurbsmotion.sim.eds import default_eds_path
from nurbsmotion.sim.faults import FaultInjection, parse_fault_spec
from nurbsmotion.sim.homing import HomeSensors
from nurbsmotion.sim.io_node import SimIoNode
from nurbsmotion.sim.network import SimNetwork, SpindleSim
from nurbsmotion.sim.recording import (SetpointRecord, SetpointRecorder, SetpointSource, SyncRecord, SyncRecorder, read_csv,
                                       read_sync_csv)
from nurbsmotion.sim.servo import ServoModel
from nurbsmotion.sim.stats import DriveStats, StreamReport, stream_report
from nurbsmotion.sim.timing import MissingSetpoint, SyncSettings

__all__ = [
    "AxisParameters",
    "Cia402Axis",
    "DriveStats",
    "FaultInjection",
    "HomeSensors",
    "MissingSetpoint",
    "ServoModel",
    "SetpointRecord",
    "SetpointRecorder",
    "SetpointSource",
    "SimDrive",
    "SimIoNode",
    "SimNetwork",
    "SpindleSim",
    "StreamReport",
    "SyncRecord",
    "SyncRecorder",
    "SyncSettings",
    "default_eds_path",
    "parse_fault_spec",
    "read_csv",
    "read_sync_csv",
    "stream_report",
]
