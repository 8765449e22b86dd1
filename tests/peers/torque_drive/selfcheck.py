# Written independently from CiA 301 / 402 / 406 (no project code): checks the torque-drive peer itself with a
# minimal CANopen master built on the `canopen` package, so the peer's behaviour is known before the project's
# master is run against it.
"""Self-check of the peer, per variant: EDS content, the CiA 301 mapping procedure for TPDO1 = 0x6041 + 0x6064 +
0x6077 (accepted / aborted with the codes README.md gives), then CSP streaming with a synchronous RPDO and SYNCs:
each TPDO1 must carry the statusword / 0x6064 / 0x6077 of the history entry of its SYNC, and 0x6077 must follow
the torque rule.

    python -m tests.peers.torque_drive.selfcheck [VARIANT ...]      exit 0 if every check passes
"""
from __future__ import annotations

import os
import struct
import sys
import tempfile
import threading
import time

import canopen
from canopen.sdo import SdoAbortedError

try:
    from . import eds as peer_eds
    from . import torque_peer as tp
except ImportError:
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import eds as peer_eds
    import torque_peer as tp


def _abort(fn):
    try:
        fn()
        return None
    except SdoAbortedError as e:
        return e.code


def check(variant, workdir):
    fails = []

    def expect(cond, what):
        if not cond:
            fails.append(what)

    d_eds = peer_eds.drive_eds(os.path.join(workdir, f"drive_{variant}.eds"), variant)
    e_eds = peer_eds.encoder_eds(os.path.join(workdir, "encoder.eds"))
    od = canopen.import_od(d_eds, 1)
    expect((0x6077 in od) == (variant != "none"), "EDS 0x6077 presence")
    if 0x6077 in od:
        expect(od[0x6077].pdo_mappable and not od[0x6077].writable, "EDS 0x6077 PDOMapping=1, ro")
        expect(not od[0x6076].writable and od[0x6076].default == peer_eds.RATED_TORQUE_MNM, "EDS 0x6076")
    expect(od[0x1A00][1].writable == (variant != "static"), "EDS 0x1A00 access")
    channel = f"selfcheck_{variant}_{time.time_ns()}"
    with tp.TorqueRig(channel, variant, drive_eds=d_eds, encoder_eds=e_eds, device_timestamps=False) as peer:
        net = canopen.Network()
        net.connect(interface="virtual", channel=channel, receive_own_messages=False)
        try:
            drive = canopen.RemoteNode(1, d_eds)
            net.add_node(drive)
            sdo = drive.sdo
            sdo.RESPONSE_TIMEOUT = 0.5

            def w(i, s, fmt, v):
                return _abort(lambda: sdo.download(i, s, struct.pack(fmt, v)))

            # SDO uploads: expedited and segmented (0x1008 is 8 bytes)
            expect(sdo.upload(0x1008, 0) == b"PEER-402", "segmented upload 0x1008")
            if variant == "none":
                expect(_abort(lambda: sdo.upload(0x6077, 0)) == 0x06020000, "0x6077 absent: 0x06020000")
                expect(_abort(lambda: sdo.upload(0x6076, 0)) == 0x06020000, "0x6076 absent: 0x06020000")
            else:
                expect(struct.unpack("<I", sdo.upload(0x6076, 0))[0] == peer_eds.RATED_TORQUE_MNM, "0x6076 value")
                expect(w(0x6076, 0, "<I", 1) == 0x06010002, "0x6076 read-only")
                expect(w(0x6077, 0, "<h", 1) == 0x06010002, "0x6077 read-only")
            # CiA 301 mapping procedure for TPDO1
            entries = [0x60410010, 0x60640020, 0x60770010]
            r = [w(0x1800, 1, "<I", 0x80000181), w(0x1A00, 0, "<B", 0)]
            if variant == "static":
                expect(r == [0x06010002, 0x06010002], f"static: comm/mapping writes abort 0x06010002, got {r}")
                expect(w(0x1800, 2, "<B", 1) == 0x06010002, "static: 0x1800:2 read-only")
                expect(w(0x1A00, 1, "<I", 0x60770010) == 0x06010002, "static: 0x1A00:1 read-only")
                mapped = entries[:2]
            else:
                expect(r == [None, None], f"disable + sub0=0 accepted, got {r}")
                # entries while sub0 != 0 / while valid are refused: checked on 0x1A01
                expect(w(0x1A01, 1, "<I", 0x60410010) == tp.ABORT_STATE, "entry write with PDO valid refused")
                r = [w(0x1A00, 1, "<I", entries[0]), w(0x1A00, 2, "<I", entries[1]), w(0x1A00, 3, "<I", entries[2])]
                want = {"mappable": [None, None, None], "refuses": [None, None, 0x06040041],
                        "none": [None, None, 0x06020000]}[variant]
                expect(r == want, f"entries: {r} want {want}")
                expect(w(0x1A00, 4, "<I", 0x60400010) is None, "0x6040 (rw, mappable) accepted in a TPDO entry")
                expect(w(0x1A00, 4, "<I", 0x60650020) == 0x06040041, "0x6065 (not mappable) refused")
                expect(w(0x1A00, 4, "<I", 0x60640010) == 0x06040041, "wrong length refused")
                mapped = entries if variant == "mappable" else entries[:2]
                expect(w(0x1A00, 4, "<I", 0) is None, "clear entry 4")
                if variant == "mappable":   # 64-bit limit: 8 + 4 bytes
                    expect(w(0x1A00, 4, "<I", 0x60640020) is None, "entry 4")
                    expect(w(0x1A00, 0, "<B", 4) == 0x06040042, "sub0 = 4 (96 bits) -> 0x06040042")
                expect(w(0x1A00, 0, "<B", len(mapped)) is None, f"sub0 = {len(mapped)}")
                expect(w(0x1A00, 1, "<I", 0x60410010) == tp.ABORT_STATE, "entry write with sub0 != 0 refused")
                expect(w(0x1800, 2, "<B", 1) is None, "transmission type 1")
                expect(w(0x1800, 1, "<I", 0x181) is None, "enable TPDO1")
            expect(w(0x1400, 1, "<I", 0x80000201) is None and w(0x1600, 0, "<B", 0) is None
                   and w(0x1600, 1, "<I", 0x60770010) in (0x06040041, 0x06020000), "0x6077 refused in an RPDO")
            # RPDO1 = controlword + target, synchronous
            for args in ((0x1600, 1, "<I", 0x60400010), (0x1600, 2, "<I", 0x607A0020), (0x1600, 0, "<B", 2),
                         (0x1400, 2, "<B", 1), (0x1400, 1, "<I", 0x201), (0x1006, 0, "<I", 1000),
                         (0x6060, 0, "<b", 8), (0x607A, 0, "<i", tp.START)):
                expect(w(*args) is None, f"write 0x{args[0]:04X}:{args[1]}")
            frames = []
            got = threading.Event()

            def on_tpdo(can_id, data, ts):
                frames.append(bytes(data))
                got.set()
            net.subscribe(0x181, on_tpdo)
            net.send_message(0x000, [0x01, 0])          # NMT start all
            time.sleep(0.05)
            for cw in (0x06, 0x07, 0x0F):
                w(0x6040, 0, "<H", cw)
            expect(peer.drive.state == tp.OE, f"enabled ({peer.drive.state})")
            targets = [tp.START + 3 * i * i for i in range(40)] + [tp.START + 3 * 39 * 39 - 200 * i for i in range(20)]
            sent = []
            for tgt in targets:
                net.send_message(0x201, struct.pack("<Hi", 0x0F, tgt))
                net.send_message(0x201, struct.pack("<Hi", 0x0F, tgt))   # the same again: last frame wins
                sent.append(tgt)
                got.clear()
                net.send_message(0x80, b"")
                got.wait(0.2)
            time.sleep(0.05)
            w(0x6040, 0, "<H", 0x02)                       # quick stop
            time.sleep(0.05)
            expect(peer.drive.state == tp.SOD, f"quick stop -> SWITCH ON DISABLED ({peer.drive.state})")
            hist = peer.history
            expect(len(frames) == len(targets) == len(hist), f"{len(frames)} TPDO1 for {len(targets)} SYNCs")
            prev_actual = None
            for k, (f, h) in enumerate(zip(frames, hist)):
                fmt = "<Hih" if len(mapped) == 3 else "<Hi"
                vals = struct.unpack(fmt, f)
                expect(h["target"] == sent[k], f"SYNC {k + 1}: applied target {h['target']} != sent {sent[k]}")
                expect(vals[0] == h["statusword"] and vals[1] == h["actual"],
                       f"SYNC {k + 1}: TPDO {vals} vs history {h}")
                if len(mapped) == 3:
                    expect(vals[2] == h["torque_permille"], f"SYNC {k + 1}: torque {vals[2]} vs {h}")
                if variant != "none":
                    want = max(-32768, min(32767, tp.TORQUE_HOLD + tp.TORQUE_GAIN * (sent[k] - h["actual"])))
                    expect(h["torque_permille"] == want, f"SYNC {k + 1}: torque rule {h['torque_permille']} != {want}")
                else:
                    expect(h["torque_permille"] is None, "none: no torque in the history")
                if prev_actual is not None:
                    expect(h["actual"] == sent[k - 1], f"SYNC {k + 1}: actual {h['actual']} != target k-1")
                expect(h["encoder"] == tp.encoder_counts(h["actual"]), "encoder value")
                prev_actual = h["actual"]
            if variant != "none":
                v = struct.unpack("<h", sdo.upload(0x6077, 0))[0]
                expect(v == hist[-1]["torque_permille"], f"SDO 0x6077 = {v}, last latched {hist[-1]['torque_permille']}")
        finally:
            net.disconnect()
    return fails


def main(argv=None):
    variants = (sys.argv[1:] if argv is None else argv) or list(peer_eds.VARIANTS)
    bad = 0
    with tempfile.TemporaryDirectory() as work:
        for v in variants:
            fails = check(v, work)
            bad += bool(fails)
            print(f"{v:10s} {'ok' if not fails else 'FAIL'}", *fails[:10], sep="\n    " if fails else " ")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
