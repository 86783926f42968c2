"""CANopen master: bring-up of CiA-402 drives, SYNC + RPDO set-point streaming, monitoring.

It streams arrays of counts (one row per cycle) and knows no curves: planning, geometry,
program and sim are never imported here.
"""

from nurbsmotion.fieldbus.busload import BusLoad, check_bus_load, cyclic_bus_load, frame_bits
from nurbsmotion.fieldbus.job import Job
from nurbsmotion.fieldbus.master import Master
from nurbsmotion.fieldbus.reports import AxisStatus, CycleStats, FaultReport, JobResult, MasterStatus

__all__ = ["AxisStatus", "BusLoad", "CycleStats", "FaultReport", "Job", "JobResult", "Master", "MasterStatus",
           "check_bus_load", "cyclic_bus_load", "frame_bits"]
