"""Every test here that puts devices on python-can's in-process ``virtual`` bus gets a bus with one frame
order, as a real CAN bus has (:mod:`sim_backend.virtual_bus_order` says why python-can's does not). The
simulated devices install it when they go on the bus; the devices written from the standards alone
(``spec_cia402_drive``, ``spec_raw_can_device``) import nothing of ours, so without this their runs got the
order only when a simulated device had come first in the same worker: a master's SDO request could reach the
drive between a SYNC's copies, and the drive's answer reach the master before that SYNC, which no bus does."""

from sim_backend.virtual_bus_order import one_bus_order

one_bus_order()
