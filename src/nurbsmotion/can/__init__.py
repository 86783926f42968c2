"""CAN and CANopen helpers the master (fieldbus) and the simulated drives (sim) share:
CiA-402 and CiA-301 constants (cia402), reading a drive description (drive_od), the
frames' arrival timeline (arrival_clock) and python-can's SocketCAN bus with batched system
calls (socketcan_batch). No master or drive logic of their own."""
