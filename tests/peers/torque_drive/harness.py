# CONFORMANCE HARNESS - written independently (from CiA 301/402/406 and the project's command line used as a black
# box: `rig --help`, `rig run --help`), without reading the project's code. The config and the experiment are
# written as /work/shared/conformance/canopen/peer_ip_cli.py writes them. Do NOT edit it to make the master pass.
"""Run the project's command line (``rig.cli.main(["run", ...])``, in-process: python-can's virtual bus is per
process) against the torque-drive peer of one variant.

    from tests.peers.torque_drive.harness import run_rig
    r = run_rig("mappable", "/tmp/work")          # -> dict, see run_rig

    python -m tests.peers.torque_drive.harness VARIANT WORKDIR [SAMPLES]    (from the project root)
"""
from __future__ import annotations

import contextlib
import io
import json
import math
import os
import sys
import time

try:
    from . import eds as peer_eds
    from . import torque_peer as tp
except ImportError:          # run as a plain script
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import eds as peer_eds
    import torque_peer as tp

HERE = os.path.dirname(os.path.abspath(__file__))
PROJECT_ROOT = os.path.dirname(os.path.dirname(os.path.dirname(HERE)))     # tests/peers/torque_drive -> root
RATE_HZ = 1000.0                 # 1 ms period
CPR = 131072                     # drive counts per revolution ([drive] counts_per_revolution)
ENCODER_BITS = 16
START = tp.START


def config_text(name, channel, drive_eds, encoder_eds):
    return f"""name = "peer_torque_{name}"
description = "independent CiA 402 drive with torque actual value 0x6077 ({name}) on the virtual bus"
sample_rate_hz = {RATE_HZ}
[transport]
url = "canopen://virtual/{channel}"
bitrate = 1000000
drive_node_id = 1
encoder_node_id = 2
drive_eds = "{drive_eds}"
encoder_eds = "{encoder_eds}"
heartbeat_ms = 100
heartbeat_timeout_s = 0.5
sdo_timeout_s = 0.5
mode = "csp"
[drive]
counts_per_revolution = {CPR}
[encoder]
bits = {ENCODER_BITS}
multi_turn_bits = 0
signed = false
[limits]
position_min_rad = -12.0
position_max_rad = 12.0
rate_max_rad_per_s = 5000.0
[watchdog]
feedback_timeout_s = 0.2
"""


def write_experiment(path, samples):
    """The conformance experiment: START + 0.5 rad * sin(2 pi 2 Hz t), one sample per ms."""
    with open(path, "w") as f:
        f.write("time_s,command_rad\n")
        start_rad = START * 2 * math.pi / CPR
        for i in range(samples):
            t = i / RATE_HZ
            f.write(f"{t:.18e},{start_rad + 0.5 * math.sin(2 * math.pi * 2 * t):.18e}\n")
    return path


def run_rig(variant, workdir, samples=400, *, bus="ordered", stderr_lines=8):
    """Run `rig run` against the peer of ``variant`` ("mappable", "static", "refuses", "none").

    Writes into workdir: drive.eds, encoder.eds, rig.toml, cmd.csv, run.csv (the log), stderr.txt,
    peer_events.txt, peer_history.json. Returns
      {"variant", "exit" (rig's exit code, or "uncaught <exc>"), "stderr_tail" (last ``stderr_lines`` non-empty
       lines of rig's stderr), "log" (path of the log, None if none was written), "final_state" (the drive's
       CiA 402 state 0.3 s after rig returned), "history" (peer's per-SYNC list of dicts: sync, target, actual,
       torque_permille, state, statusword, mode, demand, encoder, t_s), "sdo" (requests the peer received:
       [t, node, "r"/"w", "0xIIII", sub, value]), "aborts" ([t, node, "0xIIII", sub, "0xCODE"]), "events",
       "wall_s", "drive_eds", "encoder_eds"}.
    bus: "ordered" (one frame order for all receivers, device-timed TPDO stamps; the conformance default) or
    "raw" (python-can's plain virtual bus)."""
    if PROJECT_ROOT not in sys.path:
        sys.path.insert(0, PROJECT_ROOT)
    from rig.cli import main as rig_main

    workdir = os.path.abspath(workdir)
    os.makedirs(workdir, exist_ok=True)
    drive_eds = peer_eds.drive_eds(os.path.join(workdir, "drive.eds"), variant)
    encoder_eds = peer_eds.encoder_eds(os.path.join(workdir, "encoder.eds"), bits=ENCODER_BITS)
    channel = f"peertorque_{variant}_{time.time_ns()}"
    toml = os.path.join(workdir, "rig.toml")
    with open(toml, "w") as f:
        f.write(config_text(variant, channel, drive_eds, encoder_eds))
    cmd = write_experiment(os.path.join(workdir, "cmd.csv"), samples)
    log = os.path.join(workdir, "run.csv")
    if os.path.exists(log):
        os.remove(log)
    if bus == "ordered":
        tp.ordered_virtual_bus()
    out = {"variant": variant, "drive_eds": drive_eds, "encoder_eds": encoder_eds}
    err = io.StringIO()
    with tp.TorqueRig(channel, variant, drive_eds=drive_eds, encoder_eds=encoder_eds,
                      device_timestamps=bus == "ordered") as peer:
        t0 = time.perf_counter()
        with contextlib.redirect_stderr(err):
            try:
                out["exit"] = rig_main(["run", toml, "--experiment", cmd, "--out", log, "--json"])
            except SystemExit as e:
                out["exit"] = e.code
            except BaseException as e:  # noqa: BLE001
                import traceback
                out["exit"] = f"uncaught {type(e).__name__}: {e}"
                traceback.print_exc(file=err)
        out["wall_s"] = round(time.perf_counter() - t0, 2)
        time.sleep(0.3)
        out["final_state"] = peer.drive.state
        out["history"] = list(peer.history)
        out["events"] = [[round(t, 4), k, w] for t, k, w in peer.events]
        out["sdo"] = [[round(t, 4), n, rw, f"0x{i:04X}", s, v] for t, n, rw, i, s, v in peer.sdo]
        out["aborts"] = [[round(t, 4), n, f"0x{i:04X}" if i is not None else None, s, f"0x{c:08X}"]
                         for t, n, i, s, c in peer.aborts]
    text = err.getvalue()
    lines = [l for l in text.splitlines() if l.strip()]
    out["stderr_tail"] = lines[-stderr_lines:]
    out["log"] = log if os.path.exists(log) else None
    with open(os.path.join(workdir, "stderr.txt"), "w") as f:
        f.write(text)
    with open(os.path.join(workdir, "peer_events.txt"), "w") as f:
        f.write("\n".join(f"{t:.4f} {k} {w}" for t, k, w in out["events"]) + "\n")
    with open(os.path.join(workdir, "peer_history.json"), "w") as f:
        json.dump(out["history"], f)
    return out


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) < 2:
        print(__doc__)
        return 2
    r = run_rig(argv[0], argv[1], int(argv[2]) if len(argv) > 2 else 400)
    short = {k: v for k, v in r.items() if k not in ("history", "events", "sdo")}
    short["syncs"] = len(r["history"])
    print(json.dumps(short, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
