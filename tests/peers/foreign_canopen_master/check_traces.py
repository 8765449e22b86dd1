#!/usr/bin/env python3
"""check_traces.py - independent self-check of traces written by foreign_master.py.

For every case directory (default: traces/*/) this script
  1. reads trace.blf with can.BLFReader,
  2. reconstructs the PDO configuration ONLY from the bus (SDO expedited
     downloads, request/response paired) or, for eds-only, ONLY from the DCF
     files, and compares it with truth.json["mapping"],
  3. decodes every SYNC window with that mapping (TPDOs after SYNC i and before
     SYNC i+1 belong to SYNC i; RPDOs received between SYNC i-1 and SYNC i are
     taken over at SYNC i) and compares with truth.json["syncs"],
  4. re-computes the documented drive/encoder model from the truth values and
     checks that truth.json is self-consistent,
  5. checks the start-up / shut-down sequence (NMT, state machine, no EMCY).
It does not import foreign_master.py.  Exit status 0 = all checks passed.
"""
import configparser
import glob
import json
import math
import os
import re
import sys

import can

# CiA 402 / 406 object data types needed to decode PDO contents (signedness).
SIGNED_OBJECTS = {(0x607A, 0), (0x6064, 0), (0x6062, 0), (0x60C1, 1), (0x6060, 0), (0x6061, 0)}


class Checker:
    def __init__(self, case_dir):
        self.dir = case_dir
        self.name = os.path.basename(case_dir.rstrip("/"))
        self.errors = []
        self.notes = []

    def err(self, msg):
        if len(self.errors) < 40:
            self.errors.append(msg)

    def expect(self, cond, msg):
        if not cond:
            self.err(msg)
        return cond

    # ------------------------------------------------------------------ io
    def load(self):
        with open(os.path.join(self.dir, "truth.json")) as fh:
            self.truth = json.load(fh)
        self.frames = []
        for m in can.BLFReader(os.path.join(self.dir, "trace.blf")):
            self.expect(not m.is_extended_id, "extended frame found")
            self.expect(not m.is_remote_frame, "remote frame found")
            self.expect(len(m.data) == m.dlc, "dlc/data mismatch")
            self.frames.append((m.timestamp, m.arbitration_id, bytes(m.data)))
        ts = [f[0] for f in self.frames]
        self.expect(all(b > a for a, b in zip(ts, ts[1:])), "timestamps not strictly increasing")
        self.t0 = self.truth["timebase"]["t0_unix"]
        self.expect(len(self.frames) == self.truth["timebase"]["n_frames"], "frame count differs")

    # ------------------------------------------------------- configuration
    def od_from_sdo(self):
        writes, uploads, pending = {}, {}, {}
        n_req = 0
        for ts, cob, d in self.frames:
            if 0x601 <= cob <= 0x67F:
                node = cob - 0x600
                self.expect(node not in pending, f"two SDO requests outstanding for node {node}")
                pending[node] = d
                n_req += 1
            elif 0x581 <= cob <= 0x5FF:
                node = cob - 0x580
                req = pending.pop(node, None)
                if not self.expect(req is not None, f"SDO response without request node {node}"):
                    continue
                self.expect(req[1:4] == d[1:4], "SDO response multiplexer differs")
                ccs = req[0] >> 5
                idx, sub = req[1] | req[2] << 8, req[3]
                if ccs == 1:
                    self.expect(req[0] & 0x03 == 0x03, "non-expedited download")
                    self.expect(d[0] == 0x60, f"download not confirmed: {d.hex()}")
                    size = 4 - ((req[0] >> 2) & 3)
                    val = int.from_bytes(req[4:4 + size], "little")
                    writes.setdefault(node, {})[(idx, sub)] = (val, size)
                    writes[node].setdefault("_order", []).append((idx, sub, val))
                elif ccs == 2:
                    self.expect(d[0] & 0xE3 == 0x43, f"upload not expedited: {d.hex()}")
                    size = 4 - ((d[0] >> 2) & 3)
                    uploads.setdefault(node, {})[(idx, sub)] = int.from_bytes(d[4:4 + size], "little")
                else:
                    self.err(f"unexpected SDO ccs {ccs}")
        self.expect(not pending, "unanswered SDO request")
        od = {n: {k: v[0] for k, v in w.items() if k != "_order"} for n, w in writes.items()}
        return od, writes, uploads, n_req

    def od_from_dcf(self):
        cp = configparser.ConfigParser(strict=True, interpolation=None)
        cp.read(os.path.join(self.dir, "devices.dcf"))
        pat = re.compile(r"^Node(\d+)\.([0-9A-Fa-f]{4})(?:sub([0-9A-Fa-f]+))?$")
        od = {}
        for sec in cp.sections():
            m = pat.match(sec)
            if not m or "parametervalue" not in cp[sec]:
                continue
            node, idx = int(m.group(1)), int(m.group(2), 16)
            sub = int(m.group(3), 16) if m.group(3) else 0
            od.setdefault(node, {})[(idx, sub)] = int(cp[sec]["parametervalue"], 0)
        # cross-check the single-device DCFs named in [Topology]
        for node in od:
            fname = cp["Topology"][f"Node{node}DCFName"]
            cp1 = configparser.ConfigParser(strict=True, interpolation=None)
            cp1.read(os.path.join(self.dir, fname))
            self.expect(int(cp1["DeviceComissioning"]["NodeID"], 0) == node, "DCF NodeID mismatch")
            od1 = {}
            for sec in cp1.sections():
                m = re.match(r"^([0-9A-Fa-f]{4})(?:sub([0-9A-Fa-f]+))?$", sec)
                if m and "parametervalue" in cp1[sec]:
                    od1[(int(m.group(1), 16), int(m.group(2), 16) if m.group(2) else 0)] = \
                        int(cp1[sec]["parametervalue"], 0)
            self.expect(od1 == od[node], f"{fname} differs from devices.dcf")
        return od

    @staticmethod
    def pdos_from_od(od):
        out = []
        for node, vals in od.items():
            for comm in list(range(0x1400, 0x1600)) + list(range(0x1800, 0x1A00)):
                if (comm, 1) not in vals:
                    continue
                cobid = vals[(comm, 1)]
                if cobid & 0x80000000:
                    continue
                mp = comm + 0x200
                n = vals.get((mp, 0))
                ents = [vals[(mp, i)] for i in range(1, (n or 0) + 1)]
                out.append(dict(node=node, direction="rx" if comm < 0x1800 else "tx",
                                num=(comm & 0x1FF) + 1, cob=cobid & 0x7FF,
                                ext=bool(cobid & 0x20000000), trans=vals.get((comm, 2)),
                                entries=[(w >> 16, (w >> 8) & 0xFF, w & 0xFF) for w in ents]))
        return out

    # ---------------------------------------------------------------- main
    def run(self):
        self.load()
        tr = self.truth
        D, E = tr["nodes"]["drive"]["node_id"], tr["nodes"]["encoder"]["node_id"]
        eds = tr["variant"] == "eds-only"
        sdo_frames = [f for f in self.frames if 0x581 <= f[1] <= 0x67F]
        if eds:
            self.expect(not sdo_frames, "eds-only trace contains SDO frames")
            od = self.od_from_dcf()
            mode = od[D][(0x6060, 0)]
        else:
            od, writes, uploads, n_req = self.od_from_sdo()
            mode = od[D][(0x6060, 0)]
            self.expect(uploads.get(D, {}).get((0x1000, 0), 0) & 0xFFFF == 402, "drive 0x1000 != 402")
            self.expect(uploads.get(E, {}).get((0x1000, 0), 0) & 0xFFFF == 406, "encoder 0x1000 != 406")
            self.expect(uploads.get(D, {}).get((0x6061, 0)) == mode, "0x6061 readback != 0x6060")
            self.check_mapping_procedure(writes)
            if tr["mode"] == "ip":
                v, e = od[D][(0x60C2, 1)], od[D][(0x60C2, 2)]
                e = e - 256 if e > 127 else e
                self.expect(abs(v * 10.0 ** e - tr["period_s"]) < 1e-12, "0x60C2 != period")
        self.expect(mode == tr["mode_of_operation"], f"mode {mode} != truth")
        pdos = self.pdos_from_od(od)
        self.compare_mapping(pdos)
        self.pdos = pdos
        self.decode_and_compare(D, E)
        self.check_model()
        self.check_sequence(D, E, eds)
        return not self.errors

    def check_mapping_procedure(self, writes):
        """CiA 301 order per PDO: COB-ID invalid -> count 0 -> entries -> count -> type -> COB-ID valid."""
        for node, w in writes.items():
            seq = w["_order"]
            for i, (idx, sub, val) in enumerate(seq):
                if 0x1600 <= idx <= 0x17FF or 0x1A00 <= idx <= 0x1BFF:
                    comm = idx - 0x200
                    last_cob = [v for (x, s, v) in seq[:i] if (x, s) == (comm, 1)]
                    self.expect(last_cob and last_cob[-1] & 0x80000000,
                                f"node {node}: mapping {idx:04X} written while PDO valid")
                    if sub > 0:
                        cnt = [v for (x, s, v) in seq[:i] if (x, s) == (idx, 0)]
                        self.expect(cnt and cnt[-1] == 0,
                                    f"node {node}: {idx:04X}:{sub} written while count != 0")

    def compare_mapping(self, pdos):
        tm = self.truth["mapping"]
        got = {(p["node"], p["direction"], p["num"]): p for p in pdos}
        want = {(m["node_id"], m["direction"], m["pdo_number"]): m for m in tm}
        self.expect(set(got) == set(want), f"valid PDO set differs: {sorted(got)} vs {sorted(want)}")
        for k, m in want.items():
            p = got.get(k)
            if p is None:
                continue
            self.expect(p["cob"] == m["cob_id"], f"{k}: COB 0x{p['cob']:X} != 0x{m['cob_id']:X}")
            self.expect(not p["ext"], f"{k}: 29-bit COB-ID")
            self.expect(p["trans"] == m["transmission_type"], f"{k}: transmission type")
            self.expect(p["entries"] == [(e["index"], e["sub"], e["bits"]) for e in m["entries"]],
                        f"{k}: entries differ")

    # ------------------------------------------------------------- decode
    def decode_and_compare(self, D, E):
        tr = self.truth
        dec = {}                                  # cob -> (node, dir, fields)
        for p in self.pdos:
            off, fields = 0, []
            for idx, sub, bits in p["entries"]:
                fields.append((idx, sub, bits, off))
                off += bits
            dec[p["cob"]] = (p["node"], p["direction"], fields, off // 8)
        tgt_obj = (0x607A, 0) if tr["mode"] == "csp" else (0x60C1, 1)

        def unpack(fields, data):
            acc = int.from_bytes(data, "little")
            out = {}
            for idx, sub, bits, off in fields:
                v = (acc >> off) & ((1 << bits) - 1)
                if (idx, sub) in SIGNED_OBJECTS and v & (1 << (bits - 1)):
                    v -= 1 << bits
                out[(idx, sub)] = v
            return out

        syncs = []          # per SYNC: dict
        drive_od = {}       # values in force in the drive (RPDO taken over at SYNC, SDO immediately)
        rx_buf = {}         # RPDO values received since the last SYNC
        rx_target_frames = 0
        for ts, cob, d in self.frames:
            if cob == 0x080:
                drive_od.update(rx_buf)
                syncs.append(dict(t=ts, tp={}, target=drive_od.get(tgt_obj),
                                  cw=drive_od.get((0x6040, 0)), n_tgt_rpdo=rx_target_frames,
                                  rpdo_after=[]))
                rx_buf, rx_target_frames = {}, 0
            elif cob == 0x600 + D and d[0] >> 5 == 1:
                idx, sub = d[1] | d[2] << 8, d[3]
                size = 4 - ((d[0] >> 2) & 3)
                v = int.from_bytes(d[4:4 + size], "little", signed=(idx, sub) in SIGNED_OBJECTS)
                drive_od[(idx, sub)] = v
            elif cob in dec:
                node, direction, fields, dlc = dec[cob]
                self.expect(len(d) == dlc, f"PDO 0x{cob:X} DLC {len(d)} != {dlc}")
                vals = unpack(fields, d)
                if direction == "rx":
                    rx_buf.update(vals)
                    if tgt_obj in vals:
                        rx_target_frames += 1
                        if syncs:
                            syncs[-1]["rpdo_after"].append(vals[tgt_obj])
                elif syncs:
                    self.expect(cob not in syncs[-1]["tp"], f"TPDO 0x{cob:X} twice in one SYNC window")
                    syncs[-1]["tp"][cob] = vals
                else:
                    self.err(f"TPDO 0x{cob:X} before first SYNC")
        recs = tr["syncs"]
        self.expect(len(syncs) == len(recs) == tr["n_syncs"], "SYNC count differs")
        drv_tx = [p["cob"] for p in self.pdos if p["node"] == D and p["direction"] == "tx"]
        enc_tx = [p["cob"] for p in self.pdos if p["node"] == E and p["direction"] == "tx"]
        k0, n = tr["first_streaming_sync_index"], tr["n_streaming"]
        comp = tr["command"]
        late_found, lost_found = [], []
        for i, (s, r) in enumerate(zip(syncs, recs)):
            self.expect(r["i"] == i, "record index")
            self.expect(abs(s["t"] - r["t"]) < 2e-6, f"SYNC {i} timestamp {s['t']} vs {r['t']}")
            self.expect(round((s["t"] - self.t0) * 1e6) == r["t_rel_us"], f"SYNC {i} t_rel_us")
            phase = "pre" if i < k0 else ("stream" if i < k0 + n else "post")
            self.expect(r["phase"] == phase, f"SYNC {i} phase")
            got = {}
            for cob in drv_tx:
                got.update(s["tp"].get(cob, {}))
            self.expect(got.get((0x6041, 0)) == r["sw"], f"SYNC {i} sw {got.get((0x6041, 0))} vs {r['sw']}")
            self.expect(got.get((0x6064, 0)) == r["pos"], f"SYNC {i} pos {got.get((0x6064, 0))} vs {r['pos']}")
            self.expect(got.get((0x6062, 0)) == r["demand"], f"SYNC {i} demand")
            enc = None
            for cob in enc_tx:
                enc = s["tp"].get(cob, {}).get((0x6004, 0), enc)
            self.expect(enc == r["enc"], f"SYNC {i} enc {enc} vs {r['enc']}")
            if r["enc_lost"]:
                lost_found.append(i)
                self.expect(enc is None, "lost encoder TPDO is present")
            elif r["sw"] is not None:
                self.expect(enc is not None, f"SYNC {i}: encoder TPDO missing but not flagged lost")
            # set-point in force
            if r["target"] is not None:
                self.expect(s["target"] == r["target"], f"SYNC {i} target {s['target']} vs {r['target']}")
                if i + 1 < len(recs) and recs[i + 1]["sw"] is not None:
                    self.expect(recs[i + 1]["sw"] & 0x6F == 0x27, f"SYNC {i}: target but not OE next")
            elif i + 1 < len(recs) and recs[i + 1]["sw"] is not None and recs[i + 1]["sw"] & 0x6F == 0x27:
                self.expect(tr["mode"] == "ip" and not (s["cw"] or 0) & 0x10,
                            f"SYNC {i}: OE without target outside inactive IP")
            if phase == "stream":
                tau = (i - k0) * tr["period_s"]
                x = comp["base_counts"] + round(sum(c["amplitude"] * math.sin(
                    2 * math.pi * c["freq_hz"] * tau + c["phase_rad"]) for c in comp["components"]))
                self.expect(r["target_intended"] == x, f"SYNC {i} intended {r['target_intended']} vs {x}")
                late = s["n_tgt_rpdo"] == 0
                self.expect(r["rpdo_late"] == late, f"SYNC {i} rpdo_late flag")
                if late:
                    late_found.append(i)
                    self.expect(x in s["rpdo_after"], f"SYNC {i}: late RPDO not found after its SYNC")
                    self.expect(r["target"] == recs[i - 1]["target"], f"SYNC {i}: late but target changed")
                else:
                    self.expect(r["target"] == x, f"SYNC {i}: target {r['target']} != intended {x}")
                self.expect(r["sw"] is not None and r["sw"] & 0x6F == 0x27, f"SYNC {i}: stream not OE")
                if tr["mode"] == "ip" and i > k0:
                    self.expect(r["sw"] & 0x1000, f"SYNC {i}: IP active bit 12 missing")
            else:
                self.expect(r["target_intended"] is None and not r["rpdo_late"], f"SYNC {i} pre/post flags")
        imp = tr["imperfections"]
        self.expect(late_found == imp["late_rpdo_sync_indices"], f"late {late_found} vs {imp['late_rpdo_sync_indices']}")
        self.expect(lost_found == imp["lost_encoder_sync_indices"], f"lost {lost_found} vs {imp['lost_encoder_sync_indices']}")
        self.syncs = syncs
        dts = [b["t"] - a["t"] for a, b in zip(syncs, syncs[1:])]
        mean = sum(dts) / len(dts)
        self.expect(abs(mean - tr["period_s"]) < 0.01 * tr["period_s"], f"mean SYNC period {mean}")
        self.notes.append(f"SYNC period mean {mean*1e6:.2f} us, min {min(dts)*1e6:.0f}, max {max(dts)*1e6:.0f}")
        self.notes.append(f"late RPDO at {late_found}, lost encoder TPDO at {lost_found}")

    # ---------------------------------------------------------------- model
    def check_model(self):
        tr, recs = self.truth, self.truth["syncs"]
        ph = tr["physics"]
        tau, r_enc = ph["tau_s"], ph["encoder_counts_per_drive_count"]
        p = recs[0]["pos_exact"]
        worst = 0.0
        for i, r in enumerate(recs):
            if i > 0:
                prev = recs[i - 1]
                dt = (r["t_ns"] - prev["t_ns"]) * 1e-9
                e = math.exp(-dt / tau)
                x = prev["target"]
                if x is not None:
                    if tr["mode"] == "csp":
                        p = x + (p - x) * e
                    else:
                        a = recs[i - 2]["target"] if i >= 2 and recs[i - 2]["target"] is not None \
                            else prev["pos_exact"]
                        v = (x - a) / dt
                        p = x - v * tau + (p - a + v * tau) * e
                worst = max(worst, abs(p - r["pos_exact"]))
                p = r["pos_exact"]
            if r["pos"] is not None:
                self.expect(r["pos"] == math.floor(r["pos_exact"] + 0.5), f"SYNC {i}: pos rounding")
            enc = (ph["encoder_offset"] + math.floor(ph["encoder_direction"] * r["pos_exact"] * r_enc + 0.5)) \
                % ph["encoder_total_range"]
            self.expect(enc == r["enc_model"], f"SYNC {i}: encoder model {enc} vs {r['enc_model']}")
            if r["enc"] is not None:
                self.expect(r["enc"] == r["enc_model"], f"SYNC {i}: enc != enc_model")
            if r["demand"] is not None and i > 0 and recs[i - 1]["target"] is not None:
                self.expect(r["demand"] == recs[i - 1]["target"], f"SYNC {i}: demand != previous target")
        self.expect(worst < 1e-6, f"model re-computation differs by {worst}")
        self.notes.append(f"model re-computation max |dp| = {worst:.2e} counts")

    # ------------------------------------------------------------- sequence
    def check_sequence(self, D, E, eds):
        tr = self.truth
        fr = self.frames
        first_sync_t = next(f[0] for f in fr if f[1] == 0x080)
        last_sync_t = [f[0] for f in fr if f[1] == 0x080][-1]
        nmt = [(f[0], f[2][0], f[2][1]) for f in fr if f[1] == 0x000]
        starts = {n for t, cs, n in nmt if cs == 0x01 and t < first_sync_t}
        self.expect({D, E} <= starts, "NMT start of both nodes before the first SYNC missing")
        self.expect(not [f for f in fr if 0x081 <= f[1] <= 0x0FF], "EMCY frames present")
        for t, cob, d in fr:
            if 0x701 <= cob <= 0x77F:
                self.expect(len(d) == 1 and d[0] in (0x00, 0x04, 0x05, 0x7F), "bad heartbeat")
        if not eds:
            self.expect(nmt and nmt[0][1] in (0x81, 0x82), "trace does not start with NMT reset")
        if tr["imperfections"]["clean_end"]:
            pre = {n for t, cs, n in nmt if cs == 0x80 and t > last_sync_t}
            self.expect({D, E} <= pre, "NMT pre-operational at the end missing")
            k_end = tr["first_streaming_sync_index"] + tr["n_streaming"]
            cws = [s["cw"] for s in self.syncs[k_end:]]
            self.expect(0x06 in cws, "controlword 0x0006 at the end missing")
            self.expect(tr["syncs"][-1]["sw"] & 0x6F == 0x21, "drive not 'ready to switch on' at end")
        # state machine sequence seen in the statusword
        states = []
        for r in tr["syncs"]:
            if r["sw"] is None:
                continue
            st = {0x40: "SOD"}.get(r["sw"] & 0x4F) or {0x21: "RTSO", 0x23: "SO", 0x27: "OE"}.get(r["sw"] & 0x6F, "?")
            if not states or states[-1] != st:
                states.append(st)
        want = ["SOD", "RTSO", "SO", "OE"] + (["RTSO"] if tr["imperfections"]["clean_end"] else [])
        self.expect(states == want, f"statusword state sequence {states}")
        self.notes.append("state sequence " + "->".join(states))


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    dirs = sys.argv[1:] or sorted(glob.glob(os.path.join(here, "traces", "*", "")))
    ok = True
    for d in dirs:
        c = Checker(d)
        try:
            passed = c.run()
        except Exception as exc:          # report, do not hide
            c.err(f"exception: {exc!r}")
            passed = False
        ok &= passed
        print(f"[{'PASS' if passed else 'FAIL'}] {c.name}: {len(c.frames) if hasattr(c, 'frames') else 0} frames; "
              + "; ".join(c.notes))
        for e in c.errors:
            print("    ERROR", e)
    print("ALL PASSED" if ok else "SOME CHECKS FAILED")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
