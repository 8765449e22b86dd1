"""The simulated gearbox rig.

Pure-numpy physics (plant blocks, encoder, noise) plus device front-ends that speak the real wire
protocols (CANopen nodes on python-can's virtual bus, a raw-CAN responder, a serial device on a pty), so
tests and the demo drive the real transport code. May import ``identify`` and ``rig.protocols`` only.
"""
