"""The motion service: daemon, one-job-at-a-time controller, control API on a Unix socket,
job records, and the client the CLI uses. Only the service and the CLI put the layers
(program, planning, axes, fieldbus, sim) together; each meets the service in one adapter
module: planner.py (program + planning + axes) and link.py (fieldbus + sim).
"""
