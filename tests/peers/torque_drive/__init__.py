"""Torque-drive CANopen peer (CiA 402 drive with 0x6076/0x6077 + CiA 406 encoder), written independently of the
project's code; see README.md. harness.run_rig(variant, workdir, samples=400) runs `rig run` against it."""
