#!/usr/bin/env python3
"""foreign_master.py - clean-room simulator of a third-party CANopen master
streaming position set-points to a CiA 402 drive and reading a CiA 406 encoder.

Writes a CAN trace (BLF via python-can's can.Logger) plus a ground-truth JSON
(and, for --variant eds-only, DCF files).  Written only from the CiA 301 / 402 /
406 / 306 standards as remembered by the author and python-can's public API; see
README.md for every modelling assumption.

Usage:
  python foreign_master.py --variant foreign|default-ish|eds-only --mode csp|ip \
         --cycles 2000 --out DIR [--period-us 1000] [--imperfect] ...
"""
from __future__ import annotations

import argparse
import heapq
import json
import math
import os
import random
import sys

import can

GENERATOR_VERSION = "1.0"
MS = 1_000_000   # ns
US = 1_000       # ns

# --------------------------------------------------------------------------- #
# CAN physical layer: exact length of a classical base-format data frame      #
# --------------------------------------------------------------------------- #

def _crc15(bits):
    crc = 0
    for b in bits:
        nxt = b ^ ((crc >> 14) & 1)
        crc = (crc << 1) & 0x7FFF
        if nxt:
            crc ^= 0x4599
    return crc


_FRAME_BITS_CACHE: dict = {}


def frame_bits(cob: int, data: bytes) -> int:
    """Bits from SOF to the end of EOF (stuff bits included, IFS excluded)."""
    key = (cob, bytes(data))
    if key in _FRAME_BITS_CACHE:
        return _FRAME_BITS_CACHE[key]
    raw = [0] + [(cob >> (10 - i)) & 1 for i in range(11)] + [0, 0, 0]
    raw += [(len(data) >> (3 - i)) & 1 for i in range(4)]
    for byte in data:
        raw += [(byte >> (7 - i)) & 1 for i in range(8)]
    crc = _crc15(raw)
    raw += [(crc >> (14 - i)) & 1 for i in range(15)]
    stuff, last, run = 0, None, 0
    for b in raw:
        if b == last:
            run += 1
        else:
            last, run = b, 1
        if run == 5:
            stuff += 1
            last, run = 1 - b, 1
    n = len(raw) + stuff + 10          # + CRC delimiter, ACK slot, ACK delimiter, 7 EOF
    if len(_FRAME_BITS_CACHE) < 200000:
        _FRAME_BITS_CACHE[key] = n
    return n


# --------------------------------------------------------------------------- #
# Discrete-event bus simulator with CAN arbitration                           #
# --------------------------------------------------------------------------- #

class Frame:
    __slots__ = ("ready", "seq", "cob", "data", "sender", "tag", "t_start", "t_end")

    def __init__(self, ready, seq, cob, data, sender, tag):
        self.ready, self.seq, self.cob, self.data = ready, seq, cob, bytes(data)
        self.sender, self.tag = sender, tag
        self.t_start = self.t_end = None


class Bus:
    def __init__(self, bitrate: int):
        if 1_000_000_000 % bitrate:
            raise ValueError("bitrate must divide 1e9 (ns bit time)")
        self.bit_ns = 1_000_000_000 // bitrate
        self.now = 0
        self._ev = []
        self._pending = []
        self._seq = 0
        self.bus_free = 0
        self.log: list[Frame] = []
        self.nodes = []
        self.end_time = None

    def at(self, t, fn):
        heapq.heappush(self._ev, (int(t), self._seq, fn))
        self._seq += 1

    def send(self, ready, cob, data, sender, tag=None):
        self._seq += 1
        self._pending.append(Frame(int(ready), self._seq, cob, data, sender, tag))

    def _run_events_before(self, t_limit, inclusive):
        while self._ev and (self._ev[0][0] < t_limit or (inclusive and self._ev[0][0] == t_limit)):
            t, _, fn = heapq.heappop(self._ev)
            if self.end_time is not None and t > self.end_time:
                continue
            self.now = t
            fn()

    def run(self):
        while True:
            start = None
            if self._pending:
                start = max(self.bus_free, min(f.ready for f in self._pending))
            if self._ev and (start is None or self._ev[0][0] <= start):
                t, _, fn = heapq.heappop(self._ev)
                if self.end_time is not None and t > self.end_time:
                    if start is None:
                        continue
                    continue
                self.now = t
                fn()
                continue
            if start is None:
                break
            if self.end_time is not None and start > self.end_time:
                break
            cands = [f for f in self._pending if f.ready <= start]
            f = min(cands, key=lambda fr: (fr.cob, fr.seq))        # arbitration
            self._pending.remove(f)
            f.t_start = start
            f.t_end = start + frame_bits(f.cob, f.data) * self.bit_ns
            self.bus_free = f.t_end + 3 * self.bit_ns            # intermission
            # things that happen while the frame is on the wire
            self._run_events_before(f.t_end, inclusive=False)
            self.now = f.t_end
            self.log.append(f)
            for n in self.nodes:
                n.on_frame(f)


# --------------------------------------------------------------------------- #
# Object dictionary                                                           #
# --------------------------------------------------------------------------- #
# CiA 301 data type codes
BOOLEAN, INTEGER8, INTEGER16, INTEGER32 = 0x1, 0x2, 0x3, 0x4
UNSIGNED8, UNSIGNED16, UNSIGNED32 = 0x5, 0x6, 0x7
TYPE_INFO = {INTEGER8: (1, True), INTEGER16: (2, True), INTEGER32: (4, True),
             UNSIGNED8: (1, False), UNSIGNED16: (2, False), UNSIGNED32: (4, False),
             BOOLEAN: (1, False)}
VAR, ARRAY, RECORD = 0x7, 0x8, 0x9


class Entry:
    __slots__ = ("name", "dtype", "access", "default", "default_expr", "pdo")

    def __init__(self, name, dtype, access, default, default_expr=None, pdo=0):
        self.name, self.dtype, self.access = name, dtype, access
        self.default, self.default_expr, self.pdo = default, default_expr, pdo


class OD:
    def __init__(self):
        self.objects = {}       # index -> (name, objtype, [subs])
        self.entries = {}       # (index, sub) -> Entry
        self.values = {}        # (index, sub) -> int

    def var(self, idx, name, dtype, access, default, pdo=0, expr=None):
        self.objects[idx] = (name, VAR, [0])
        self.entries[(idx, 0)] = Entry(name, dtype, access, default, expr, pdo)
        self.values[(idx, 0)] = default

    def rec(self, idx, name, objtype, subs):
        self.objects[idx] = (name, objtype, [s[0] for s in subs])
        for s in subs:
            sub, sname, dtype, access, default = s[:5]
            pdo = s[5] if len(s) > 5 else 0
            expr = s[6] if len(s) > 6 else None
            self.entries[(idx, sub)] = Entry(sname, dtype, access, default, expr, pdo)
            self.values[(idx, sub)] = default

    def reset_comm(self):
        for key, e in self.entries.items():
            if 0x1000 <= key[0] <= 0x1FFF:
                self.values[key] = e.default


def add_comm_objects(od: OD, node_id, device_type, n_rpdo, n_tpdo, rpdo_defaults, tpdo_defaults,
                     identity):
    od.var(0x1000, "Device type", UNSIGNED32, "ro", device_type)
    od.var(0x1001, "Error register", UNSIGNED8, "ro", 0)
    od.var(0x1017, "Producer heartbeat time", UNSIGNED16, "rw", 0)
    od.rec(0x1018, "Identity object", RECORD, [
        (0, "Highest sub-index supported", UNSIGNED8, "const", 4),
        (1, "Vendor-ID", UNSIGNED32, "ro", identity[0]),
        (2, "Product code", UNSIGNED32, "ro", identity[1]),
        (3, "Revision number", UNSIGNED32, "ro", identity[2]),
        (4, "Serial number", UNSIGNED32, "ro", identity[3])])
    for n in range(n_rpdo):
        base, flags, ttype, entries = rpdo_defaults[n]
        od.rec(0x1400 + n, f"RPDO{n+1} communication parameter", RECORD, [
            (0, "Highest sub-index supported", UNSIGNED8, "const", 2),
            (1, "COB-ID used by RPDO", UNSIGNED32, "rw", flags | (base + node_id), 0,
             f"$NODEID+0x{flags | base:X}"),
            (2, "Transmission type", UNSIGNED8, "rw", ttype)])
        subs = [(0, "Number of mapped application objects in PDO", UNSIGNED8, "rw", len(entries))]
        for i in range(8):
            subs.append((i + 1, f"Application object {i+1}", UNSIGNED32, "rw",
                         entries[i] if i < len(entries) else 0))
        od.rec(0x1600 + n, f"RPDO{n+1} mapping parameter", RECORD, subs)
    for n in range(n_tpdo):
        base, flags, ttype, entries = tpdo_defaults[n]
        od.rec(0x1800 + n, f"TPDO{n+1} communication parameter", RECORD, [
            (0, "Highest sub-index supported", UNSIGNED8, "const", 5),
            (1, "COB-ID used by TPDO", UNSIGNED32, "rw", flags | (base + node_id), 0,
             f"$NODEID+0x{flags | base:X}"),
            (2, "Transmission type", UNSIGNED8, "rw", ttype),
            (3, "Inhibit time", UNSIGNED16, "rw", 0),
            (5, "Event timer", UNSIGNED16, "rw", 0)])
        subs = [(0, "Number of mapped application objects in PDO", UNSIGNED8, "rw", len(entries))]
        for i in range(8):
            subs.append((i + 1, f"Application object {i+1}", UNSIGNED32, "rw",
                         entries[i] if i < len(entries) else 0))
        od.rec(0x1A00 + n, f"TPDO{n+1} mapping parameter", RECORD, subs)


def mapword(idx, sub, bits):
    return (idx << 16) | (sub << 8) | bits


def build_drive_od(node_id, p):
    od = OD()
    invalid = 0x80000000
    rpdo = [(0x200, 0, 0xFF, [mapword(0x6040, 0, 16)]),
            (0x300, 0, 0xFF, [mapword(0x6040, 0, 16), mapword(0x6060, 0, 8)]),
            (0x400, invalid, 0xFF, [mapword(0x6040, 0, 16), mapword(0x607A, 0, 32)]),
            (0x500, invalid, 0xFF, [mapword(0x6040, 0, 16), mapword(0x60FF, 0, 32)])]
    tpdo = [(0x180, 0x40000000, 0xFF, [mapword(0x6041, 0, 16)]),
            (0x280, 0x40000000, 0xFF, [mapword(0x6041, 0, 16), mapword(0x6061, 0, 8)]),
            (0x380, 0xC0000000, 0xFF, [mapword(0x6041, 0, 16), mapword(0x6064, 0, 32)]),
            (0x480, 0xC0000000, 0xFF, [mapword(0x6041, 0, 16), mapword(0x606C, 0, 32)])]
    add_comm_objects(od, node_id, 0x00020192, 4, 4, rpdo, tpdo,
                     (0x00FFFF01, 0x00004020, 0x00010003, 0x12340003))
    od.var(0x1006, "Communication cycle period", UNSIGNED32, "rw", 0)
    od.var(0x6040, "Controlword", UNSIGNED16, "rww", 0, pdo=1)
    od.var(0x6041, "Statusword", UNSIGNED16, "ro", 0x0250, pdo=1)
    od.var(0x6060, "Modes of operation", INTEGER8, "rw", 0, pdo=1)
    od.var(0x6061, "Modes of operation display", INTEGER8, "ro", 0, pdo=1)
    od.var(0x6062, "Position demand value", INTEGER32, "ro", 0, pdo=1)
    od.var(0x6064, "Position actual value", INTEGER32, "ro", 0, pdo=1)
    od.var(0x606C, "Velocity actual value", INTEGER32, "ro", 0, pdo=1)
    od.var(0x607A, "Target position", INTEGER32, "rww", 0, pdo=1)
    od.rec(0x608F, "Position encoder resolution", RECORD, [
        (0, "Highest sub-index supported", UNSIGNED8, "const", 2),
        (1, "Encoder increments", UNSIGNED32, "rw", p["drive_counts_per_motor_rev"]),
        (2, "Motor revolutions", UNSIGNED32, "rw", 1)])
    od.rec(0x6091, "Gear ratio", RECORD, [
        (0, "Highest sub-index supported", UNSIGNED8, "const", 2),
        (1, "Motor shaft revolutions", UNSIGNED32, "rw", p["gear_motor_revs"]),
        (2, "Driving shaft revolutions", UNSIGNED32, "rw", p["gear_load_revs"])])
    od.var(0x60C0, "Interpolation sub mode select", INTEGER16, "rw", 0)
    od.rec(0x60C1, "Interpolation data record", ARRAY, [
        (0, "Highest sub-index supported", UNSIGNED8, "ro", 1),
        (1, "Interpolation data record 1", INTEGER32, "rww", 0, 1)])
    od.rec(0x60C2, "Interpolation time period", RECORD, [
        (0, "Highest sub-index supported", UNSIGNED8, "const", 2),
        (1, "Interpolation time period value", UNSIGNED8, "rw", 1),
        (2, "Interpolation time index", INTEGER8, "rw", -3)])
    od.var(0x60FF, "Target velocity", INTEGER32, "rww", 0, pdo=1)
    od.var(0x6502, "Supported drive modes", UNSIGNED32, "ro", 0x000003E5)
    return od


def build_encoder_od(node_id, p):
    od = OD()
    tpdo = [(0x180, 0x40000000, 0xFE, [mapword(0x6004, 0, 32)]),
            (0x280, 0x40000000, 0x01, [mapword(0x6004, 0, 32)])]
    add_comm_objects(od, node_id, 0x00020196, 0, 2, [], tpdo,
                     (0x00FFFF02, 0x00000406, 0x00020001, 0x56780009))
    od.var(0x6000, "Operating parameters", UNSIGNED16, "rw", 0x0004)
    od.var(0x6001, "Measuring units per revolution", UNSIGNED32, "rw", p["enc_counts_per_rev"])
    od.var(0x6002, "Total measuring range in measuring units", UNSIGNED32, "rw", p["enc_range"])
    od.var(0x6003, "Preset value", UNSIGNED32, "rw", 0)
    od.var(0x6004, "Position value", UNSIGNED32, "ro", 0, pdo=1)
    od.var(0x6501, "Singleturn resolution", UNSIGNED32, "ro", p["enc_counts_per_rev"])
    od.var(0x6502, "Number of distinguishable revolutions", UNSIGNED16, "ro",
           p["enc_range"] // p["enc_counts_per_rev"])
    return od


def to_bytes(value, dtype):
    size, signed = TYPE_INFO[dtype]
    return int(value).to_bytes(size, "little", signed=signed)


def from_bytes(b, dtype):
    size, signed = TYPE_INFO[dtype]
    return int.from_bytes(bytes(b[:size]), "little", signed=signed)


# --------------------------------------------------------------------------- #
# Generic CANopen slave                                                        #
# --------------------------------------------------------------------------- #
PREOP, OPERATIONAL, STOPPED = 0x7F, 0x05, 0x04


class Slave:
    def __init__(self, bus: Bus, node_id, od: OD, rng, jitter, name):
        self.bus, self.id, self.od, self.rng, self.jitter, self.name = bus, node_id, od, rng, jitter, name
        self.nmt = PREOP
        self.hb_gen = 0
        self.sync_count = 0
        self.rpdo_buf = {}      # pdo number -> (data, tag)
        self.boot_delay_ns = 3 * MS
        self.sdo_delay = (250 * US, 1200 * US, 500 * US)
        self.tpdo_delay = (30 * US, 70 * US, 50 * US)
        self.tpdo_ctr = {}

    # ---- helpers
    def rand_delay(self, spec):
        lo, hi, fixed = spec
        return self.rng.randint(lo, hi) if self.jitter else fixed

    def pdo_table(self, rx):
        comm0, map0 = (0x1400, 0x1600) if rx else (0x1800, 0x1A00)
        out = []
        for n in range(512):
            if (comm0 + n, 1) not in self.od.values:
                break
            cobid = self.od.values[(comm0 + n, 1)]
            if cobid & 0x80000000:
                continue
            cnt = self.od.values[(map0 + n, 0)]
            ents = [self.od.values[(map0 + n, i + 1)] for i in range(cnt)]
            out.append((n + 1, cobid & 0x7FF, self.od.values[(comm0 + n, 2)], ents))
        return out

    def pack(self, ents):
        acc, nbits = 0, 0
        for w in ents:
            idx, sub, bits = w >> 16, (w >> 8) & 0xFF, w & 0xFF
            v = self.od.values[(idx, sub)] & ((1 << bits) - 1)
            acc |= v << nbits
            nbits += bits
        return acc.to_bytes((nbits + 7) // 8, "little")

    def unpack_into_od(self, ents, data):
        acc = int.from_bytes(data, "little")
        pos = 0
        for w in ents:
            idx, sub, bits = w >> 16, (w >> 8) & 0xFF, w & 0xFF
            raw = (acc >> pos) & ((1 << bits) - 1)
            pos += bits
            _, signed = TYPE_INFO[self.od.entries[(idx, sub)].dtype]
            if signed and raw & (1 << (bits - 1)):
                raw -= 1 << bits
            self.write_od(idx, sub, raw, via="pdo")

    def write_od(self, idx, sub, value, via="sdo"):
        self.od.values[(idx, sub)] = value
        if (idx, sub) == (0x1017, 0):
            self.start_heartbeat(value)
        self.after_write(idx, sub, value, via)

    def after_write(self, idx, sub, value, via):
        pass

    # ---- heartbeat
    def start_heartbeat(self, ms, first_delay=None):
        self.hb_gen += 1
        gen = self.hb_gen
        if not ms:
            return

        def beat():
            if gen != self.hb_gen:
                return
            self.bus.send(self.bus.now, 0x700 + self.id, bytes([self.nmt]), self)
            self.bus.at(self.bus.now + ms * MS, beat)
        self.bus.at(self.bus.now + (first_delay if first_delay is not None else ms * MS), beat)

    # ---- reception
    def on_frame(self, f: Frame):
        if f.sender is self:
            return
        t = f.t_end
        if f.cob == 0x000 and len(f.data) == 2:
            cs, target = f.data
            if target in (0, self.id):
                self.on_nmt(cs, t)
        elif f.cob == 0x080:
            self.on_sync(t)
        elif f.cob == 0x600 + self.id:
            self.on_sdo(f, t)
        elif self.nmt == OPERATIONAL:
            for n, cob, ttype, ents in self.pdo_table(rx=True):
                if cob == f.cob:
                    need = sum(w & 0xFF for w in ents) // 8
                    if len(f.data) < need:
                        continue
                    if ttype <= 240:
                        self.rpdo_buf[n] = (f.data, f.tag)   # latest one wins
                    else:
                        self.unpack_into_od(ents, f.data[:need])

    def on_nmt(self, cs, t):
        if cs == 0x01:
            self.nmt = OPERATIONAL
        elif cs == 0x02:
            self.nmt = STOPPED
        elif cs == 0x80:
            self.nmt = PREOP
            self.rpdo_buf.clear()
        elif cs in (0x81, 0x82):
            self.od.reset_comm()
            self.hb_gen += 1
            self.rpdo_buf.clear()
            self.nmt = None       # initialising

            def boot():
                self.nmt = PREOP
                self.bus.send(self.bus.now, 0x700 + self.id, b"\x00", self)
            self.bus.at(t + self.boot_delay_ns + (self.rng.randint(0, 2 * MS) if self.jitter else 0), boot)

    def on_sdo(self, f, t):
        d = f.data
        ccs = d[0] >> 5
        idx, sub = d[1] | (d[2] << 8), d[3]
        mux = bytes(d[1:4])
        key = (idx, sub)
        resp = None
        if key not in self.od.entries:
            resp = bytes([0x80]) + mux + (0x06020000).to_bytes(4, "little")
        elif ccs == 1:                      # initiate download
            e, s, n = (d[0] >> 1) & 1, d[0] & 1, (d[0] >> 2) & 3
            if not (e and s):
                resp = bytes([0x80]) + mux + (0x05040001).to_bytes(4, "little")
            else:
                size = 4 - n
                dtype = self.od.entries[key].dtype
                if TYPE_INFO[dtype][0] != size:
                    resp = bytes([0x80]) + mux + (0x06070010).to_bytes(4, "little")
                else:
                    self.write_od(idx, sub, from_bytes(d[4:4 + size], dtype), via="sdo")
                    resp = bytes([0x60]) + mux + b"\x00\x00\x00\x00"
        elif ccs == 2:                      # initiate upload
            dtype = self.od.entries[key].dtype
            size = TYPE_INFO[dtype][0]
            raw = to_bytes(self.od.values[key], dtype)
            resp = bytes([0x40 | ((4 - size) << 2) | 0x3]) + mux + raw + bytes(4 - size)
        else:
            resp = bytes([0x80]) + mux + (0x05040001).to_bytes(4, "little")
        self.bus.send(t + self.rand_delay(self.sdo_delay), 0x580 + self.id, resp, self)

    # ---- SYNC
    def on_sync(self, t):
        k = self.sync_count
        self.sync_count += 1
        self.before_latch(t, k)
        sent = []
        if self.nmt == OPERATIONAL and not self.skip_tx(k):
            ready = t + self.rand_delay(self.tpdo_delay)
            for n, cob, ttype, ents in self.pdo_table(rx=False):
                if 1 <= ttype <= 240:
                    c = self.tpdo_ctr.get(n, 0) + 1
                    self.tpdo_ctr[n] = c
                    if c % ttype == 0:
                        data = self.pack(ents)
                        self.bus.send(ready, cob, data, self, tag=("tpdo", k))
                        sent.append(cob)
        tags = {}
        if self.nmt == OPERATIONAL:
            rx = {n: (cob, ttype, ents) for n, cob, ttype, ents in self.pdo_table(rx=True)}
            for n in sorted(self.rpdo_buf):
                data, tag = self.rpdo_buf[n]
                if n in rx and rx[n][1] <= 240:
                    ents = rx[n][2]
                    need = sum(w & 0xFF for w in ents) // 8
                    self.unpack_into_od(ents, data[:need])
                    for w in ents:
                        tags[(w >> 16, (w >> 8) & 0xFF)] = tag
        self.rpdo_buf.clear()
        self.after_takeover(t, k, tags, sent)

    def before_latch(self, t, k):
        pass

    def skip_tx(self, k):
        return False

    def after_takeover(self, t, k, tags, sent):
        pass


# --------------------------------------------------------------------------- #
# CiA 402 drive                                                               #
# --------------------------------------------------------------------------- #
SOD, RTSO, SO, OE = "switch_on_disabled", "ready_to_switch_on", "switched_on", "operation_enabled"
SW_BASE = {SOD: 0x0250, RTSO: 0x0231, SO: 0x0233, OE: 0x0237}


class Drive(Slave):
    def __init__(self, bus, node_id, od, rng, jitter, phys, csp_bit12=True):
        super().__init__(bus, node_id, od, rng, jitter, "drive")
        self.boot_delay_ns = 4 * MS
        self.tpdo_delay = (30 * US, 70 * US, 50 * US)
        self.sdo_delay = (250 * US, 1200 * US, 500 * US)
        self.phys = phys
        self.tau = phys["tau_s"]
        self.p = float(phys["p_init"])
        self.profile = ("frozen",)
        self.d_end = self.p
        self.t_last = None
        self.state = SOD
        self.ip_active = False
        self.ip_prev = self.p
        self.csp_bit12 = csp_bit12
        self.records = []

    def after_write(self, idx, sub, value, via):
        if (idx, sub) == (0x6060, 0):
            self.od.values[(0x6061, 0)] = value

    def statusword(self):
        sw = SW_BASE[self.state]
        if self.state == OE:
            mode = self.od.values[(0x6060, 0)]
            if (mode == 8 and self.csp_bit12) or (mode == 7 and self.ip_active):
                sw |= 0x1000
        return sw

    def _integrate(self, t):
        dt = (t - self.t_last) * 1e-9
        e = math.exp(-dt / self.tau)
        kind = self.profile[0]
        if kind == "hold":
            x = self.profile[1]
            self.p = x + (self.p - x) * e
            self.d_end = x
        elif kind == "ramp":
            a, b = self.profile[1], self.profile[2]
            v = (b - a) / dt
            self.p = b - v * self.tau + (self.p - a + v * self.tau) * e
            self.d_end = b
        else:
            self.d_end = self.p

    def before_latch(self, t, k):
        if self.t_last is not None:
            self._integrate(t)
        self.t_last = t
        self.od.values[(0x6064, 0)] = math.floor(self.p + 0.5)       # nearest count
        self.od.values[(0x6062, 0)] = math.floor(self.d_end + 0.5)
        self.od.values[(0x6041, 0)] = self.statusword()
        self._latched = dict(t_ns=t, state=self.state, sw=self.od.values[(0x6041, 0)],
                             pos=self.od.values[(0x6064, 0)], demand=self.od.values[(0x6062, 0)],
                             pos_exact=self.p)

    def _transition(self, cw):
        s = self.state
        if not cw & 0x02:                           # disable voltage
            return SOD
        if (cw & 0x06) == 0x02:                      # quick stop
            return SOD                               # (quick-stop-active not modelled)
        if not cw & 0x01:                            # shutdown xxxx x110
            return RTSO if s in (SOD, SO, OE) else s
        if not cw & 0x08:                            # switch on / disable operation 0111
            return SO if s in (RTSO, OE) else s
        # enable operation 1111
        if s == SO:
            return OE
        if s == RTSO:
            return SO                                # transition 3 now, 4 next cycle
        return s

    def after_takeover(self, t, k, tags, sent):
        cw = self.od.values[(0x6040, 0)]
        old = self.state
        self.state = self._transition(cw)
        mode = self.od.values[(0x6060, 0)]
        target, tag = None, None
        if self.state == OE:
            if old != OE:
                self.ip_prev = self.p
                self.ip_active = False
            if mode == 8:
                target = self.od.values[(0x607A, 0)]
                tag = tags.get((0x607A, 0))
                self.profile = ("hold", float(target))
            elif mode == 7:
                self.ip_active = bool(cw & 0x10)
                if self.ip_active:
                    target = self.od.values[(0x60C1, 1)]
                    tag = tags.get((0x60C1, 1))
                    self.profile = ("ramp", self.ip_prev, float(target))
                    self.ip_prev = float(target)
                else:
                    self.profile = ("hold", self.ip_prev)
            else:
                self.profile = ("hold", self.p)
        else:
            self.ip_active = False
            self.profile = ("frozen",)
        rec = dict(self._latched)
        rec.update(i=k, tpdo_sent=bool(sent), target=target, target_tag=tag,
                   cw_taken=cw, state_after=self.state)
        self.records.append(rec)


# --------------------------------------------------------------------------- #
# CiA 406 encoder                                                             #
# --------------------------------------------------------------------------- #

class Encoder(Slave):
    def __init__(self, bus, node_id, od, rng, jitter, phys, drive: Drive, lost=()):
        super().__init__(bus, node_id, od, rng, jitter, "encoder")
        self.boot_delay_ns = 2 * MS
        self.tpdo_delay = (20 * US, 80 * US, 40 * US)
        self.sdo_delay = (200 * US, 800 * US, 400 * US)
        self.phys, self.drive = phys, drive
        self.lost = set(lost)
        self.records = []

    def value_from_drive_position(self, p):
        ph = self.phys
        r = ph["enc_counts_per_rev"] / (ph["drive_counts_per_motor_rev"] * ph["gear_motor_revs"]
                                        / ph["gear_load_revs"])
        return (ph["enc_offset"] + math.floor(ph["enc_direction"] * p * r + 0.5)) % ph["enc_range"]

    def before_latch(self, t, k):
        assert self.drive.t_last == t, "drive must process SYNC first"
        self.od.values[(0x6004, 0)] = self.value_from_drive_position(self.drive.p)

    def skip_tx(self, k):
        return k in self.lost

    def after_takeover(self, t, k, tags, sent):
        self.records.append(dict(i=k, value=self.od.values[(0x6004, 0)], sent=bool(sent),
                                 lost=k in self.lost and self.nmt == OPERATIONAL))


# --------------------------------------------------------------------------- #
# Mapping variants                                                            #
# --------------------------------------------------------------------------- #

def default_mapping(variant, mode, with_demand=True):
    """Returns the mapping spec. cob_base is added to the node-ID."""
    base = "default-ish" if variant == "default-ish" else "foreign"
    if base == "foreign":
        if mode == "csp":
            rx = [dict(num=3, cob_base=0x400, trans=1,
                       entries=[(0x6040, 0, 16), (0x607A, 0, 32)])]
        else:
            rx = [dict(num=1, cob_base=0x200, trans=1, entries=[(0x6040, 0, 16)]),
                  dict(num=3, cob_base=0x400, trans=1, entries=[(0x60C1, 1, 32)])]
        tx = [dict(num=2, cob_base=0x280, trans=1, entries=[(0x6064, 0, 32), (0x6041, 0, 16)])]
        if with_demand:
            tx.append(dict(num=3, cob_base=0x380, trans=1, entries=[(0x6062, 0, 32)]))
        enc = [dict(num=1, cob_base=0x1A0, trans=1, entries=[(0x6004, 0, 32)])]
        tpdo_bit30 = True
    else:
        tgt = (0x607A, 0, 32) if mode == "csp" else (0x60C1, 1, 32)
        rx = [dict(num=1, cob_base=0x200, trans=1, entries=[(0x6040, 0, 16), tgt])]
        tx = [dict(num=1, cob_base=0x180, trans=1, entries=[(0x6041, 0, 16), (0x6064, 0, 32)])]
        if with_demand:
            tx.append(dict(num=2, cob_base=0x280, trans=1, entries=[(0x6062, 0, 32)]))
        enc = [dict(num=1, cob_base=0x180, trans=1, entries=[(0x6004, 0, 32)])]
        tpdo_bit30 = False
    return dict(drive=dict(rpdo=rx, tpdo=tx), encoder=dict(rpdo=[], tpdo=enc),
                tpdo_cobid_bit30=tpdo_bit30)


def normalise_mapping(m):
    for dev in ("drive", "encoder"):
        m.setdefault(dev, {}).setdefault("rpdo", [])
        m[dev].setdefault("tpdo", [])
        for p in m[dev]["rpdo"] + m[dev]["tpdo"]:
            p["entries"] = [tuple(int(x, 0) if isinstance(x, str) else int(x) for x in e)
                            for e in p["entries"]]
            p.setdefault("trans", 1)
            for k in ("cob", "cob_base"):
                if isinstance(p.get(k), str):
                    p[k] = int(p[k], 0)
    m.setdefault("tpdo_cobid_bit30", False)
    return m


def pdo_cob(p, node_id):
    return p["cob"] if "cob" in p and p["cob"] is not None else p["cob_base"] + node_id


# --------------------------------------------------------------------------- #
# Master                                                                      #
# --------------------------------------------------------------------------- #

class Master:
    def __init__(self, bus: Bus, cfg, mapping, drive_od_default, enc_od_default, rng):
        self.bus, self.cfg, self.mapping, self.rng = bus, cfg, mapping, rng
        self.D, self.E = cfg["drive_id"], cfg["encoder_id"]
        self.T = cfg["period_us"] * US
        self.jitter = cfg["jitter"]
        self.rng_sync = random.Random(cfg["seed"] * 7 + 1)
        self.sync_jit = []
        self.sync_running = False
        self.sync_base = None
        self.sync_sent = 0           # number of SYNC frames on the bus
        self.sync_timer_k = 0
        self.wait = None
        self.gen = None
        self.sw = None
        self.pos = None
        self.rpdo_on = False
        self.cw = 0
        self.hold_target = 0
        self.stream_request = False
        self.k0 = None
        self.stream_finished = False
        self.x_last = None
        self.intended = {}
        self.late_streams = set(cfg["late_rpdo_syncs"])   # absolute SYNC indices (filled later)
        self.late_offsets = cfg["late_rpdo_offsets"]
        self.events = []              # (t_ns, text)
        self.drive_od_default = drive_od_default
        self.enc_od_default = enc_od_default
        self.ended = False
        # decoders for the drive TPDOs (master knows its own configuration)
        self.dec = {}
        for p in mapping["drive"]["tpdo"]:
            cob = pdo_cob(p, self.D)
            off = 0
            fields = {}
            for idx, sub, bits in p["entries"]:
                fields[(idx, sub)] = (off, bits)
                off += bits
            self.dec[cob] = fields

    # ---------- timing helpers
    def d(self, lo_us, hi_us, fixed_us):
        return (self.rng.randint(lo_us * US, hi_us * US) if self.jitter else fixed_us * US)

    def sync_time(self, k):
        while len(self.sync_jit) <= k:
            if self.jitter:
                j = max(-30.0, min(30.0, self.rng_sync.gauss(0.0, 10.0)))
                self.sync_jit.append(int(round(j * US)))
            else:
                self.sync_jit.append(0)
        return self.sync_base + k * self.T + self.sync_jit[k]

    # ---------- coroutine machinery
    def start(self):
        self.gen = self.script()
        self._advance(None)

    def _advance(self, val):
        try:
            w = self.gen.send(val)
        except StopIteration:
            return
        kind = w[0]
        if kind == "delay":
            self.bus.at(self.bus.now + w[1], lambda: self._advance(None))
        elif kind == "frame":
            self.wait = w[1]
        else:
            raise ValueError(kind)

    def log_event(self, text):
        self.events.append((self.bus.now, text))

    # ---------- reception
    def on_frame(self, f: Frame):
        if f.sender is self and f.cob == 0x080:
            self.on_own_sync(f)
        if f.cob in self.dec and f.sender is not self:
            flds = self.dec[f.cob]
            acc = int.from_bytes(f.data, "little")
            if (0x6041, 0) in flds:
                o, b = flds[(0x6041, 0)]
                self.sw = (acc >> o) & ((1 << b) - 1)
            if (0x6064, 0) in flds:
                o, b = flds[(0x6064, 0)]
                v = (acc >> o) & ((1 << b) - 1)
                self.pos = v - (1 << b) if v & (1 << (b - 1)) else v
        if self.wait is not None and self.wait(f):
            self.wait = None
            react = self.d(80, 400, 200)
            self.bus.at(f.t_end + react, lambda fr=f: self._advance(fr))

    # ---------- SYNC production and cyclic RPDO output
    def start_sync(self, t_first):
        self.sync_base = t_first
        self.sync_running = True
        self.sync_timer_k = 0
        self.bus.at(self.sync_time(0), self._sync_timer)

    def _sync_timer(self):
        if not self.sync_running:
            return
        data = b""
        if self.cfg["sync_counter"]:
            data = bytes([(self.sync_timer_k % 240) + 1])
        self.bus.send(self.bus.now, 0x080, data, self)
        self.sync_timer_k += 1
        self.bus.at(self.sync_time(self.sync_timer_k), self._sync_timer)

    def cmd(self, s):
        c = self.cfg["command"]
        tau = (s - self.k0) * self.T * 1e-9
        v = 0.0
        for comp in c["components"]:
            v += comp["amplitude"] * math.sin(2 * math.pi * comp["freq_hz"] * tau + comp["phase_rad"])
        return int(self.hold_target + round(v))

    def on_own_sync(self, f):
        k = self.sync_sent
        self.sync_sent += 1
        s = k + 1
        if self.stream_request and self.k0 is None:
            self.k0 = s
            self.stream_request = False
            for off in self.late_offsets:
                self.late_streams.add(self.k0 + off)
        if not self.rpdo_on:
            return
        cyc = self.cfg["cycles"]
        tag = None
        if self.k0 is not None and self.k0 <= s < self.k0 + cyc:
            target = self.cmd(s)
            tag = s
            self.intended[s] = target
            self.x_last = target
        elif self.k0 is not None and s >= self.k0 + cyc:
            target = self.x_last
        else:
            target = self.hold_target
        values = {(0x6040, 0): self.cw, (0x607A, 0): target, (0x60C1, 1): target}
        if s in self.late_streams:
            ready = self.sync_time(s) + self.d(60, 140, 100)
        else:
            ready = f.t_end + self.d(120, 380, 250)
        for p in self.mapping["drive"]["rpdo"]:
            acc, nb = 0, 0
            for idx, sub, bits in p["entries"]:
                acc |= (values[(idx, sub)] & ((1 << bits) - 1)) << nb
                nb += bits
            has_target = any((e[0], e[1]) in ((0x607A, 0), (0x60C1, 1)) for e in p["entries"])
            self.bus.send(ready, pdo_cob(p, self.D), acc.to_bytes(nb // 8, "little"), self,
                          tag=(tag if has_target else None))
        if self.k0 is not None and s == self.k0 + cyc - 1:
            self.stream_finished = True
            if self.cfg["sm_via"] == "sdo":
                self.rpdo_on = False

    # ---------- primitive actions (generators)
    def nmt(self, cs, node):
        self.bus.send(self.bus.now, 0x000, bytes([cs, node]), self)
        yield ("delay", self.d(300, 900, 500))

    def sdo_write(self, node, idx, sub, value, size):
        cmd = 0x20 | ((4 - size) << 2) | 0x3
        mux = bytes([idx & 0xFF, idx >> 8, sub])
        raw = int(value).to_bytes(size, "little", signed=value < 0)
        req = bytes([cmd]) + mux + raw + bytes(4 - size)
        self.bus.send(self.bus.now, 0x600 + node, req, self)
        r = yield ("frame", lambda f: f.cob == 0x580 + node and f.data[1:4] == mux)
        if r.data[0] != 0x60:
            raise RuntimeError(f"SDO abort node {node} {idx:04X}:{sub} {r.data.hex()}")

    def sdo_read(self, node, idx, sub):
        mux = bytes([idx & 0xFF, idx >> 8, sub])
        self.bus.send(self.bus.now, 0x600 + node, bytes([0x40]) + mux + bytes(4), self)
        r = yield ("frame", lambda f: f.cob == 0x580 + node and f.data[1:4] == mux)
        if r.data[0] & 0xE0 != 0x40:
            raise RuntimeError("SDO upload abort")
        return r

    def wait_syncs(self, n):
        target = self.sync_sent + n
        yield ("frame", lambda f: f.sender is self and f.cob == 0x080 and self.sync_sent >= target)

    def wait_sw(self, pred):
        yield ("frame", lambda f: f.cob in self.dec and self.sw is not None and pred(self.sw))

    # ---------- configuration list (shared with the eds-only silent config)
    def config_ops(self, who):
        node = self.D if who == "drive" else self.E
        mp = self.mapping[who]
        ops = [("r", 0x1000, 0)]
        ops.append(("w", 0x1017, 0, self.cfg["heartbeat_ms"], 2))
        if who == "drive":
            ops.append(("w", 0x1006, 0, self.cfg["period_us"], 4))
            ops.append(("w", 0x6060, 0, 8 if self.cfg["mode"] == "csp" else 7, 1))
            ops.append(("r", 0x6061, 0))
            if self.cfg["mode"] == "ip":
                v, e = ip_period_encoding(self.cfg["period_us"])
                ops.append(("w", 0x60C0, 0, 0, 2))
                ops.append(("w", 0x60C2, 1, v, 1))
                ops.append(("w", 0x60C2, 2, e, 1))
        od_def = self.drive_od_default if who == "drive" else self.enc_od_default
        for rx in (True, False):
            comm0, map0 = (0x1400, 0x1600) if rx else (0x1800, 0x1A00)
            used = {p["num"]: p for p in mp["rpdo" if rx else "tpdo"]}
            n_slots = sum(1 for n in range(512) if (comm0 + n, 1) in od_def.values)
            for n in range(1, n_slots + 1):                     # disable unused PDOs
                if n not in used:
                    cur = od_def.values[(comm0 + n - 1, 1)]
                    ops.append(("w", comm0 + n - 1, 1, 0x80000000 | (cur & 0x7FFFFFFF), 4))
            for n in sorted(used):                              # CiA 301 mapping procedure
                p = used[n]
                cur = od_def.values[(comm0 + n - 1, 1)]
                ops.append(("w", comm0 + n - 1, 1, 0x80000000 | (cur & 0x7FFFFFFF), 4))
                ops.append(("w", map0 + n - 1, 0, 0, 1))
                for i, (idx, sub, bits) in enumerate(p["entries"]):
                    ops.append(("w", map0 + n - 1, i + 1, mapword(idx, sub, bits), 4))
                ops.append(("w", map0 + n - 1, 0, len(p["entries"]), 1))
                ops.append(("w", comm0 + n - 1, 2, p["trans"], 1))
                cob = pdo_cob(p, node)
                if not rx and self.mapping["tpdo_cobid_bit30"]:
                    cob |= 0x40000000
                ops.append(("w", comm0 + n - 1, 1, cob, 4))
        return ops

    def run_ops(self, node, ops):
        for op in ops:
            if op[0] == "r":
                yield from self.sdo_read(node, op[1], op[2])
            else:
                yield from self.sdo_write(node, op[1], op[2], op[3], op[4])
            yield ("delay", self.d(150, 600, 300))

    # ---------- the master's application program
    def script(self):
        cfg = self.cfg
        D, E = self.D, self.E
        sm_sdo = cfg["sm_via"] == "sdo"
        csp = cfg["mode"] == "csp"
        if cfg["variant"] != "eds-only":
            self.log_event("NMT reset communication (all)")
            yield from self.nmt(0x82, 0)
            booted = set()

            def boot_pred(f):
                if f.cob in (0x700 + D, 0x700 + E) and f.data == b"\x00":
                    booted.add(f.cob - 0x700)
                return booted == {D, E}
            yield ("frame", boot_pred)
            yield ("delay", self.d(2000, 4000, 3000))
            self.log_event("configure drive")
            yield from self.run_ops(D, self.config_ops("drive"))
            self.log_event("configure encoder")
            yield from self.run_ops(E, self.config_ops("encoder"))
            yield ("delay", 2 * MS)
        else:
            yield ("delay", 1)
        self.log_event("NMT start")
        yield from self.nmt(0x01, D)
        yield from self.nmt(0x01, E)
        yield ("delay", 3 * MS)
        self.log_event("SYNC start")
        self.start_sync(self.bus.now + 1 * MS)
        yield from self.wait_syncs(8)
        yield from self.wait_sw(lambda sw: True)
        self.hold_target = self.pos
        self.log_event(f"hold target {self.hold_target}")
        is_rtso = lambda sw: (sw & 0x6F) == 0x21
        is_so = lambda sw: (sw & 0x6F) == 0x23
        is_oe = lambda sw: (sw & 0x6F) == 0x27
        if sm_sdo:
            if csp:
                yield from self.sdo_write(D, 0x607A, 0, self.hold_target, 4)
            else:
                yield from self.sdo_write(D, 0x60C1, 1, self.hold_target, 4)
            yield ("delay", self.d(150, 600, 300))
            for cw, pred in ((0x06, is_rtso), (0x07, is_so), (0x0F, is_oe)):
                self.log_event(f"controlword 0x{cw:04X} via SDO")
                yield from self.sdo_write(D, 0x6040, 0, cw, 2)
                yield from self.wait_sw(pred)
                yield from self.wait_syncs(3)
        else:
            self.cw = 0x06
            self.rpdo_on = True
            for cw, pred in ((0x06, is_rtso), (0x07, is_so), (0x0F, is_oe)):
                self.log_event(f"controlword 0x{cw:04X} via RPDO")
                self.cw = cw
                yield from self.wait_sw(pred)
                yield from self.wait_syncs(3)
        yield from self.wait_syncs(5)
        self.cw = 0x0F if csp else 0x1F
        self.rpdo_on = True
        self.stream_request = True
        self.log_event("stream request")
        yield ("frame", lambda f: self.stream_finished)
        self.log_event("stream finished")
        if not cfg["clean_end"]:
            self.bus.end_time = self.sync_time(self.k0 + cfg["cycles"] - 1) + 600 * US
            return
        yield from self.wait_syncs(cfg["hold_cycles"])
        if sm_sdo:
            self.log_event("controlword 0x0006 via SDO")
            yield from self.sdo_write(D, 0x6040, 0, 0x06, 2)
        else:
            self.log_event("controlword 0x0006 via RPDO")
            self.cw = 0x06
        yield from self.wait_sw(is_rtso)
        yield from self.wait_syncs(3)
        self.rpdo_on = False
        yield from self.wait_syncs(2)
        self.sync_running = False
        self.log_event("SYNC stop")
        yield ("delay", self.d(1500, 2500, 2000))
        self.log_event("NMT pre-operational")
        yield from self.nmt(0x80, D)
        yield from self.nmt(0x80, E)
        yield ("delay", 20 * MS)
        self.bus.end_time = self.bus.now
        self.ended = True


def ip_period_encoding(period_us):
    """0x60C2: value (UNSIGNED8) * 10^index (INTEGER8) seconds."""
    for e in (-3, -4, -5, -6):
        v = period_us * 1e-6 / (10.0 ** e)
        if abs(v - round(v)) < 1e-9 and 1 <= round(v) <= 255:
            return int(round(v)), e
    raise ValueError("period not representable in 0x60C2")


# --------------------------------------------------------------------------- #
# DCF writer (CiA 306 conventions)                                            #
# --------------------------------------------------------------------------- #

def fmt_value(v, dtype):
    size, signed = TYPE_INFO[dtype]
    if signed:
        return str(int(v))
    if size == 4:
        return f"0x{int(v):08X}"
    if size == 2:
        return f"0x{int(v):04X}" if v > 255 else str(int(v))
    return str(int(v))


def dcf_sections(od: OD, node_id, node_name, bitrate, file_name, vendor, product, created):
    sec = []   # list of (name, [(k, v)])
    sec.append(("FileInfo", [("FileName", file_name), ("FileVersion", "1"), ("FileRevision", "0"),
                             ("EDSVersion", "4.0"),
                             ("Description", f"{product} as configured by the foreign master"),
                             ("CreationTime", "12:00PM"), ("CreationDate", created),
                             ("CreatedBy", "foreign_master.py"),
                             ("ModificationTime", "12:00PM"), ("ModificationDate", created),
                             ("ModifiedBy", "foreign_master.py")]))
    n_rx = sum(1 for i in range(0x1400, 0x1600) if i in od.objects)
    n_tx = sum(1 for i in range(0x1800, 0x1A00) if i in od.objects)
    sec.append(("DeviceInfo", [("VendorName", vendor), ("VendorNumber", f"0x{od.values[(0x1018, 1)]:08X}"),
                               ("ProductName", product),
                               ("ProductNumber", f"0x{od.values[(0x1018, 2)]:08X}"),
                               ("RevisionNumber", f"0x{od.values[(0x1018, 3)]:08X}"),
                               ("OrderCode", product),
                               ("BaudRate_10", "0"), ("BaudRate_20", "0"), ("BaudRate_50", "0"),
                               ("BaudRate_125", "1"), ("BaudRate_250", "1"), ("BaudRate_500", "1"),
                               ("BaudRate_800", "0"), ("BaudRate_1000", "1"),
                               ("SimpleBootUpMaster", "0"), ("SimpleBootUpSlave", "1"),
                               ("Granularity", "8"), ("DynamicChannelsSupported", "0"),
                               ("GroupMessaging", "0"), ("NrOfRXPDO", str(n_rx)),
                               ("NrOfTXPDO", str(n_tx)), ("LSS_Supported", "0")]))
    sec.append(("DummyUsage", [(f"Dummy000{i}", "0") for i in range(1, 8)]))
    sec.append(("Comments", [("Lines", "2"),
                             ("Line1", "Values in ParameterValue are the configuration in force during the trace."),
                             ("Line2", "Generated by foreign_master.py (clean-room test data).")]))
    idxs = sorted(od.objects)
    mand = [i for i in idxs if i in (0x1000, 0x1001, 0x1018)]
    opt = [i for i in idxs if i not in mand and (0x1000 <= i <= 0x1FFF or 0x6000 <= i <= 0xFFFF)]
    man = [i for i in idxs if 0x2000 <= i <= 0x5FFF]
    for title, lst in (("MandatoryObjects", mand), ("OptionalObjects", opt), ("ManufacturerObjects", man)):
        sec.append((title, [("SupportedObjects", str(len(lst)))] +
                    [(str(j + 1), f"0x{i:04X}") for j, i in enumerate(lst)]))
    for idx in idxs:
        name, otype, subs = od.objects[idx]
        if otype == VAR:
            e = od.entries[(idx, 0)]
            sec.append((f"{idx:04X}", entry_kv(e, od.values[(idx, 0)], name)))
        else:
            sec.append((f"{idx:04X}", [("ParameterName", name), ("ObjectType", f"0x{otype:X}"),
                                       ("SubNumber", str(len(subs)))]))
            for s in subs:
                e = od.entries[(idx, s)]
                sec.append((f"{idx:04X}sub{s:X}", entry_kv(e, od.values[(idx, s)], e.name)))
    sec.append(("DeviceComissioning", [("NodeID", f"0x{node_id:02X}"), ("NodeName", node_name),
                                       ("Baudrate", str(bitrate // 1000)), ("NetNumber", "1"),
                                       ("NetworkName", "foreign_line"), ("CANopenManager", "0"),
                                       ("LSS_SerialNumber", f"0x{od.values[(0x1018, 4)]:08X}")]))
    return sec


def entry_kv(e: Entry, value, name):
    default = e.default_expr if e.default_expr else fmt_value(e.default, e.dtype)
    return [("ParameterName", name), ("ObjectType", "0x7"), ("DataType", f"0x{e.dtype:04X}"),
            ("AccessType", e.access), ("DefaultValue", default), ("PDOMapping", str(e.pdo)),
            ("ParameterValue", fmt_value(value, e.dtype))]


def write_ini(path, sections, prefix=""):
    with open(path, "w", newline="\r\n") as fh:
        for name, kvs in sections:
            fh.write(f"[{prefix}{name}]\n")
            for k, v in kvs:
                fh.write(f"{k}={v}\n")
            fh.write("\n")


# --------------------------------------------------------------------------- #
# Main                                                                        #
# --------------------------------------------------------------------------- #

def mapping_to_json(mapping, D, E):
    out = []
    for who, nid in (("drive", D), ("encoder", E)):
        for rx in (True, False):
            for p in mapping[who]["rpdo" if rx else "tpdo"]:
                cob = pdo_cob(p, nid)
                comm = (0x1400 if rx else 0x1800) + p["num"] - 1
                mapi = (0x1600 if rx else 0x1A00) + p["num"] - 1
                cobid_val = cob | (0x40000000 if (not rx and mapping["tpdo_cobid_bit30"]) else 0)
                ents, off = [], 0
                for idx, sub, bits in p["entries"]:
                    ents.append(dict(index=idx, index_hex=f"0x{idx:04X}", sub=sub, bits=bits,
                                     bit_offset=off, byte_offset=off // 8,
                                     mapping_word=f"0x{mapword(idx, sub, bits):08X}",
                                     signed=idx in (0x607A, 0x6064, 0x6062, 0x60C1),
                                     name=OBJ_NAMES.get((idx, sub), "?")))
                    off += bits
                out.append(dict(device=who, node_id=nid, direction="rx" if rx else "tx",
                                kind=("RPDO" if rx else "TPDO") + str(p["num"]), pdo_number=p["num"],
                                comm_index=f"0x{comm:04X}", mapping_index=f"0x{mapi:04X}",
                                cob_id=cob, cob_id_hex=f"0x{cob:03X}",
                                cob_id_parameter_value=f"0x{cobid_val:08X}",
                                transmission_type=p["trans"], dlc=off // 8, entries=ents))
    return out


OBJ_NAMES = {(0x6040, 0): "controlword", (0x6041, 0): "statusword",
             (0x607A, 0): "target_position", (0x6064, 0): "position_actual_value",
             (0x6062, 0): "position_demand_value", (0x60C1, 1): "interpolation_data_record_1",
             (0x6004, 0): "encoder_position_value", (0x6060, 0): "modes_of_operation"}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--variant", choices=["foreign", "default-ish", "eds-only"], default="foreign")
    ap.add_argument("--mode", choices=["csp", "ip"], default="csp")
    ap.add_argument("--cycles", type=int, default=2000, help="number of streaming SYNC cycles")
    ap.add_argument("--out", required=True)
    ap.add_argument("--period-us", type=int, default=1000)
    ap.add_argument("--bitrate", type=int, default=1_000_000)
    ap.add_argument("--drive-id", type=int, default=3)
    ap.add_argument("--encoder-id", type=int, default=9)
    ap.add_argument("--seed", type=int, default=4021)
    ap.add_argument("--mapping-json", help="override mapping (same schema as default_mapping())")
    ap.add_argument("--no-demand-tpdo", action="store_true", help="do not map 0x6062")
    ap.add_argument("--sm-via", choices=["sdo", "pdo"], help="controlword path for the CiA 402 "
                    "state machine (default: sdo, eds-only: pdo)")
    ap.add_argument("--no-jitter", action="store_true")
    ap.add_argument("--imperfect", action="store_true",
                    help="late RPDO at stream offset 1200 and lost encoder TPDO at 700 "
                         "(scaled to 60%%/35%% of --cycles if shorter)")
    ap.add_argument("--late-rpdo", type=int, action="append", default=None,
                    help="streaming-relative SYNC index whose RPDO arrives after its SYNC")
    ap.add_argument("--lost-enc", type=int, action="append", default=None,
                    help="streaming-relative SYNC index whose encoder TPDO is not sent")
    ap.add_argument("--no-clean-end", action="store_true",
                    help="cut the trace right after the last streaming cycle")
    ap.add_argument("--no-heartbeat", action="store_true")
    ap.add_argument("--sync-counter", action="store_true", help="SYNC with 1-byte counter")
    ap.add_argument("--no-csp-bit12", action="store_true", help="do not set statusword bit 12 in CSP")
    ap.add_argument("--tau-ms", type=float, default=3.0)
    ap.add_argument("--p-init", type=int, default=12345)
    ap.add_argument("--enc-offset", type=int, default=1_000_000)
    ap.add_argument("--enc-direction", type=int, choices=[1, -1], default=1)
    ap.add_argument("--t0", type=float, default=1767268800.0,
                    help="Unix time of logger start (must be a whole millisecond)")
    a = ap.parse_args(argv)

    late = list(a.late_rpdo or [])
    lost = list(a.lost_enc or [])
    if a.imperfect:
        late = late or [1200 if a.cycles > 1300 else int(a.cycles * 0.6)]
        lost = lost or [700 if a.cycles > 1300 else int(a.cycles * 0.35)]
    sm_via = a.sm_via or ("pdo" if a.variant == "eds-only" else "sdo")
    if a.variant == "eds-only" and sm_via == "sdo":
        ap.error("eds-only has no SDO traffic; use --sm-via pdo")
    if abs(a.t0 * 1000 - round(a.t0 * 1000)) > 1e-6:
        ap.error("--t0 must be a whole millisecond")

    phys = dict(tau_s=a.tau_ms * 1e-3, p_init=a.p_init, drive_counts_per_motor_rev=10000,
                gear_motor_revs=3, gear_load_revs=1, enc_counts_per_rev=8192, enc_range=1 << 25,
                enc_offset=a.enc_offset, enc_direction=a.enc_direction)
    command = dict(components=[dict(amplitude=3000.0, freq_hz=1.0, phase_rad=0.0),
                               dict(amplitude=700.0, freq_hz=6.5, phase_rad=0.0)])
    if a.mapping_json:
        with open(a.mapping_json) as fh:
            mapping = normalise_mapping(json.load(fh))
    else:
        mapping = normalise_mapping(default_mapping(a.variant, a.mode, not a.no_demand_tpdo))

    cfg = dict(variant=a.variant, mode=a.mode, cycles=a.cycles, period_us=a.period_us,
               drive_id=a.drive_id, encoder_id=a.encoder_id, seed=a.seed, jitter=not a.no_jitter,
               sm_via=sm_via, late_rpdo_syncs=[], late_rpdo_offsets=late,
               clean_end=not a.no_clean_end, heartbeat_ms=0 if a.no_heartbeat else 100,
               sync_counter=a.sync_counter, command=command, hold_cycles=50)

    rng = random.Random(a.seed)
    bus = Bus(a.bitrate)
    drive_od = build_drive_od(a.drive_id, phys)
    enc_od = build_encoder_od(a.encoder_id, phys)
    drive_def = build_drive_od(a.drive_id, phys)
    enc_def = build_encoder_od(a.encoder_id, phys)
    drive = Drive(bus, a.drive_id, drive_od, random.Random(a.seed + 11), cfg["jitter"], phys,
                  csp_bit12=not a.no_csp_bit12)
    encoder = Encoder(bus, a.encoder_id, enc_od, random.Random(a.seed + 12), cfg["jitter"], phys,
                      drive)
    master = Master(bus, cfg, mapping, drive_def, enc_def, rng)
    bus.nodes = [drive, encoder, master]

    if a.variant == "eds-only":
        # configuration happened before the logger started: apply it silently
        for who, node in (("drive", drive), ("encoder", encoder)):
            for op in master.config_ops(who):
                if op[0] == "w":
                    node.write_od(op[1], op[2], op[3], via="dcf")
        for node in (drive, encoder):
            node.hb_gen += 1
            if cfg["heartbeat_ms"]:
                node.start_heartbeat(cfg["heartbeat_ms"],
                                     first_delay=rng.randint(5 * MS, cfg["heartbeat_ms"] * MS))

    # lost encoder TPDOs are relative to the first streaming SYNC; resolved lazily
    for off in late + lost:
        if not 0 < off < a.cycles:
            ap.error(f"imperfection offset {off} outside the stream (1..cycles-1)")
    lost_rel = lost
    orig_on_own_sync = master.on_own_sync

    def on_own_sync_hook(f):
        had = master.k0
        orig_on_own_sync(f)
        if had is None and master.k0 is not None:
            encoder.lost.update(master.k0 + o for o in lost_rel)
    master.on_own_sync = on_own_sync_hook

    bus.end_time = (30 + 3 * a.cycles * a.period_us // 1000) * MS   # safety limit
    master.start()
    bus.run()
    if master.k0 is None or not master.stream_finished:
        raise RuntimeError("simulation did not complete the stream")

    os.makedirs(a.out, exist_ok=True)
    t0 = round(a.t0 * 1000) / 1000.0

    # ---- write the trace -------------------------------------------------
    frames = bus.log
    blf_path = os.path.join(a.out, "trace.blf")
    logger = can.Logger(blf_path)
    try:
        for f in frames:
            t_us = f.t_end // 1000
            msg = can.Message(timestamp=t0 + t_us * 1e-6, arbitration_id=f.cob,
                              is_extended_id=False, dlc=len(f.data), data=f.data,
                              channel=0, is_rx=True)
            logger.on_message_received(msg)
    finally:
        logger.stop()

    # ---- truth -----------------------------------------------------------
    sync_frames = [f for f in frames if f.cob == 0x080]
    n_sync = len(sync_frames)
    drec = {r["i"]: r for r in drive.records}
    erec = {r["i"]: r for r in encoder.records}
    k0, cyc = master.k0, a.cycles
    demand_mapped = any((0x6062, 0) == (e[0], e[1]) for p in mapping["drive"]["tpdo"] for e in p["entries"])
    records = []
    for i, sf in enumerate(sync_frames):
        dr, er = drec[i], erec[i]
        assert dr["t_ns"] == sf.t_end
        phase = "pre" if i < k0 else ("stream" if i < k0 + cyc else "post")
        intended = master.intended.get(i)
        late_flag = phase == "stream" and dr["target_tag"] != i
        records.append(dict(
            i=i, t=round(t0 + (sf.t_end // 1000) * 1e-6, 6), t_rel_us=sf.t_end // 1000, t_ns=sf.t_end,
            phase=phase, state=dr["state"],
            sw=dr["sw"] if dr["tpdo_sent"] else None,
            pos=dr["pos"] if dr["tpdo_sent"] else None,
            demand=(dr["demand"] if (dr["tpdo_sent"] and demand_mapped) else None),
            enc=er["value"] if er["sent"] else None,
            enc_lost=bool(er["lost"]),
            target=dr["target"], target_intended=intended, rpdo_late=bool(late_flag),
            pos_exact=round(dr["pos_exact"], 9), enc_model=er["value"]))
    mode_val = 8 if a.mode == "csp" else 7
    ipv, ipe = ip_period_encoding(a.period_us)
    first_frame_t = frames[0].t_end // 1000
    truth = dict(
        generator=dict(name="foreign_master.py", version=GENERATOR_VERSION, seed=a.seed,
                       argv=sys.argv[1:] if argv is None else argv),
        variant=a.variant, mode=a.mode, mode_of_operation=mode_val,
        bitrate=a.bitrate, period_s=a.period_us * 1e-6, period_us=a.period_us,
        nodes=dict(drive=dict(node_id=a.drive_id, profile="CiA 402", device_type="0x00020192"),
                   encoder=dict(node_id=a.encoder_id, profile="CiA 406", device_type="0x00020196")),
        master=dict(sync_producer=True, node_id=None,
                    note="the master has no node-ID of its own on the bus (no heartbeat, no EMCY)"),
        sync=dict(cob_id=0x080, counter=bool(a.sync_counter)),
        ip_time_period=dict(value=ipv, index=ipe) if a.mode == "ip" else None,
        mapping_source=("SDO downloads in the trace" if a.variant != "eds-only"
                        else "devices.dcf / node<id>.dcf (no SDO in the trace)"),
        state_machine_via=sm_via,
        mapping=mapping_to_json(mapping, a.drive_id, a.encoder_id),
        disabled_pdos="every other PDO of both nodes has bit 31 (invalid) set in its COB-ID entry",
        physics=dict(
            tau_s=phys["tau_s"], p_init_counts=phys["p_init"],
            drive_counts_per_motor_rev=phys["drive_counts_per_motor_rev"],
            gear_motor_revs_per_load_rev=phys["gear_motor_revs"] / phys["gear_load_revs"],
            encoder_counts_per_load_rev=phys["enc_counts_per_rev"],
            encoder_total_range=phys["enc_range"], encoder_offset=phys["enc_offset"],
            encoder_direction=phys["enc_direction"],
            encoder_counts_per_drive_count=phys["enc_counts_per_rev"] /
            (phys["drive_counts_per_motor_rev"] * phys["gear_motor_revs"] / phys["gear_load_revs"]),
            drive_model=("CSP: p' = (x - p)/tau with x the target in force, held constant from "
                         "SYNC k to SYNC k+1. IP: p' = (d - p)/tau with d ramping linearly from "
                         "the previous data point (at SYNC k) to the data point in force (reached "
                         "exactly at SYNC k+1). Not in operation enabled: p constant."),
            encoder_model=("enc = (encoder_offset + floor(encoder_direction * pos_exact * "
                           "encoder_counts_per_drive_count + 0.5)) mod encoder_total_range, sampled at "
                           "the same SYNC instant as the drive"),
            reported_position=("pos = floor(pos_exact + 0.5) (nearest count); demand = floor(d + 0.5) "
                               "with d the position demand at the SYNC instant, before the new "
                               "set-point is taken over")),
        command=dict(base_counts=master.hold_target, components=command["components"],
                     formula=("target_intended[i] = base_counts + round(sum_c A_c*sin(2*pi*f_c*"
                              "(i - first_streaming_sync_index)*period_s + phase_c))"),
                     units="drive position units (counts, INTEGER32)"),
        imperfections=dict(jitter=cfg["jitter"],
                           late_rpdo_sync_indices=[r["i"] for r in records if r["rpdo_late"]],
                           lost_encoder_sync_indices=[r["i"] for r in records if r["enc_lost"]],
                           late_rpdo_requested_stream_offsets=late,
                           lost_encoder_requested_stream_offsets=lost,
                           clean_end=cfg["clean_end"], emcy_frames=0,
                           heartbeat_ms=cfg["heartbeat_ms"]),
        first_streaming_sync_index=k0, n_streaming=cyc, n_syncs=n_sync,
        timebase=dict(t0_unix=t0, first_frame_t_rel_us=first_frame_t, n_frames=len(frames),
                      timestamp_point="end of frame (end of EOF), truncated to 1 us",
                      note=("'t' values equal (to ~1e-7 s) the timestamps can.BLFReader returns; "
                            "t_rel_us is relative to t0_unix (the BLF header start time)")),
        master_events=[dict(t_rel_us=t // 1000, event=txt) for t, txt in master.events],
        field_definitions=FIELD_DEFS,
    )
    write_truth(os.path.join(a.out, "truth.json"), truth, records)

    if a.variant == "eds-only":
        write_dcfs(a.out, drive_od, enc_od, a.drive_id, a.encoder_id, a.bitrate)
    print(f"{a.out}: {len(frames)} frames, {n_sync} SYNCs, first streaming SYNC {k0}, "
          f"duration {frames[-1].t_end / 1e9:.3f} s")


FIELD_DEFS = {
    "syncs[].i": "SYNC index: 0 = first SYNC frame (COB-ID 0x080) in the trace, counting every SYNC frame",
    "syncs[].t": "timestamp of that SYNC frame in the trace [s, Unix, as can.BLFReader returns it]",
    "syncs[].t_rel_us": "same, in integer microseconds after timebase.t0_unix",
    "syncs[].t_ns": "simulator-internal exact SYNC reception instant [ns after t0_unix]; the trace holds it truncated to 1 us",
    "syncs[].phase": "'pre' before first_streaming_sync_index, 'stream' for the n_streaming SYNCs from it, 'post' after",
    "syncs[].state": "CiA 402 state of the drive at the SYNC instant, i.e. the state whose statusword is latched (before this SYNC's controlword is evaluated)",
    "syncs[].sw": "statusword 0x6041 as sent in the drive's synchronous TPDO answering this SYNC (UNSIGNED16), null if no TPDO was sent",
    "syncs[].pos": "position actual value 0x6064 in that TPDO [drive counts, INTEGER32] = floor(pos_exact + 0.5)",
    "syncs[].demand": "position demand value 0x6062 in the drive TPDO answering this SYNC [drive counts, INTEGER32], null if 0x6062 is not mapped",
    "syncs[].enc": "encoder position value 0x6004 in the encoder's TPDO answering this SYNC [encoder counts, UNSIGNED32], null if that TPDO was not sent (lost)",
    "syncs[].enc_lost": "true at the SYNC whose encoder TPDO was deliberately suppressed",
    "syncs[].enc_model": "the value the encoder latched at this SYNC even when the TPDO was lost",
    "syncs[].target": "set-point the drive took over at this SYNC and uses for the following interval: 0x607A (CSP) or 0x60C1:1 (IP) after taking over RPDOs received since the previous SYNC [drive counts]; null when the drive is not in 'operation enabled' (IP: or interpolation inactive)",
    "syncs[].target_intended": "value the master computed for this SYNC (streaming SYNCs only), null otherwise",
    "syncs[].rpdo_late": "true if the RPDO carrying target_intended for this SYNC was not received before this SYNC (the drive therefore kept the previous target)",
    "syncs[].pos_exact": "model position of the drive at the SYNC instant [drive counts, float]",
}


def write_truth(path, truth, records):
    head = json.dumps(truth, indent=1)
    assert head.endswith("}")
    lines = [json.dumps(r, separators=(",", ":")) for r in records]
    with open(path, "w") as fh:
        fh.write(head[:-1].rstrip() + ',\n "syncs": [\n  ' + ",\n  ".join(lines) + "\n ]\n}\n")


def write_dcfs(out, drive_od, enc_od, D, E, bitrate):
    created = "01-01-2026"
    dsec = dcf_sections(drive_od, D, "Drive", bitrate, f"node{D}.dcf", "Example Drives (fictitious)",
                        "EXD-402 servo drive", created)
    esec = dcf_sections(enc_od, E, "Encoder", bitrate, f"node{E}.dcf", "Example Encoders (fictitious)",
                        "EXE-406 multiturn encoder", created)
    write_ini(os.path.join(out, f"node{D}.dcf"), dsec)
    write_ini(os.path.join(out, f"node{E}.dcf"), esec)
    topo = [("Topology", [("Name", "foreign_line"), ("Nodes", "0x02"),
                          (f"Node{D}Present", "0x01"), (f"Node{D}Name", "Drive"),
                          (f"Node{D}DCFName", f"node{D}.dcf"),
                          (f"Node{E}Present", "0x01"), (f"Node{E}Name", "Encoder"),
                          (f"Node{E}DCFName", f"node{E}.dcf")])]
    write_ini(os.path.join(out, "nodelist.cpj"), topo)
    with open(os.path.join(out, "devices.dcf"), "w", newline="\r\n") as fh:
        fh.write("; Combined DCF of all nodes on the line. CiA 306 defines one DCF per device;\n"
                 "; here every section of node N is prefixed 'NodeN.' (e.g. [Node3.1A01sub1]).\n"
                 f"; The unprefixed single-device files are node{D}.dcf and node{E}.dcf.\n\n")
        for name, kvs in topo:
            fh.write(f"[{name}]\n" + "".join(f"{k}={v}\n" for k, v in kvs) + "\n")
    for nid, sec in ((D, dsec), (E, esec)):
        with open(os.path.join(out, "devices.dcf"), "a", newline="\r\n") as fh:
            for name, kvs in sec:
                fh.write(f"[Node{nid}.{name}]\n" + "".join(f"{k}={v}\n" for k, v in kvs) + "\n")


if __name__ == "__main__":
    main()
