"""Three CiA 402 drives made of python `canopen` LocalNodes behind an SLCAN port: they take
machlink's SDO configuration and NMT commands, follow the CiA 402 power state machine, read
set-points from RPDOs with the mapping machlink wrote, apply them at each SYNC and report the
position by TPDO. Every SDO write, NMT command, power state change and applied set-point
goes to --trace as one JSON object per line. A quick stop ends in switch on disabled when
0x605A is 1-4 (docs/canopen.md). A node given to --stuck never leaves ready to switch on
(it ignores "switch on"), so machlink's start-up fails on it.

    python3 canopen_drives.py --port /dev/pts/N --nodes 1,2,3 --trace FILE [--stuck 3]
"""

import argparse
import json
import os
import struct
import sys
import threading
import time

import can
import canopen

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from canopen_od import drive_od  # noqa: E402

# CiA 402: (state, statusword bits 0-6)
SWITCH_ON_DISABLED, READY, SWITCHED_ON, ENABLED, QUICK_STOP, FAULT = (
    0x40, 0x21, 0x23, 0x27, 0x07, 0x08)


def command(cw, previous):
    if cw & 0x80 and not previous & 0x80:
        return "fault reset"
    if not cw & 0x02:
        return "disable voltage"
    if not cw & 0x04:
        return "quick stop"
    if not cw & 0x01:
        return "shutdown"
    if not cw & 0x08:
        return "switch on"
    return "enable operation"


TRANSITIONS = {
    (SWITCH_ON_DISABLED, "shutdown"): READY,
    (READY, "switch on"): SWITCHED_ON,
    (READY, "enable operation"): ENABLED,
    (READY, "disable voltage"): SWITCH_ON_DISABLED,
    (SWITCHED_ON, "enable operation"): ENABLED,
    (SWITCHED_ON, "shutdown"): READY,
    (SWITCHED_ON, "disable voltage"): SWITCH_ON_DISABLED,
    (ENABLED, "switch on"): SWITCHED_ON,
    (ENABLED, "shutdown"): READY,
    (ENABLED, "disable voltage"): SWITCH_ON_DISABLED,
    (ENABLED, "quick stop"): QUICK_STOP,
    (QUICK_STOP, "enable operation"): ENABLED,
    (QUICK_STOP, "disable voltage"): SWITCH_ON_DISABLED,
    (FAULT, "fault reset"): SWITCH_ON_DISABLED,
}


class Drive:
    def __init__(self, network, node_id, trace, stuck=False):
        self.id = node_id
        self.stuck = stuck
        self.trace = trace
        self.node = canopen.LocalNode(node_id, drive_od(node_id))
        network.add_node(self.node)
        self.network = network
        self.state = SWITCH_ON_DISABLED
        self.cw = 0
        self.setpoint = None
        self.position = 0
        self.syncs = 0
        self.lock = threading.Lock()
        self.node.add_write_callback(self.on_write)
        self.set(0x6041, 0, struct.pack("<H", self.state | 0x0210))
        network.subscribe(0x000, self.on_nmt)

    def set(self, index, sub, data):
        self.node.data_store.setdefault(index, {})[sub] = bytes(data)

    def u32(self, index, sub):
        return struct.unpack("<I", self.node.get_data(index, sub)[:4].ljust(4, b"\0"))[0]

    def u8(self, index, sub):
        return self.node.get_data(index, sub)[0]

    def on_write(self, index, subindex, od, data):
        self.trace({"event": "sdo_write", "node": self.id, "index": index, "sub": subindex,
                    "data": bytes(data).hex()})
        if index == 0x6040:
            cw = struct.unpack("<H", bytes(data)[:2])[0]
            with self.lock:
                cmd = command(cw, self.cw)
                nxt = TRANSITIONS.get((self.state, cmd))
                if self.stuck and cmd == "switch on":
                    nxt = None
                self.cw = cw
                if nxt == QUICK_STOP:
                    code = struct.unpack("<h", self.node.get_data(0x605A, 0)[:2])[0]
                    if 1 <= code <= 4:
                        # the ramp, then switch on disabled (0x605A = 1-4)
                        nxt = SWITCH_ON_DISABLED
                if nxt is not None and nxt != self.state:
                    self.state = nxt
                    self.trace({"event": "state", "node": self.id, "state": self.state})
                sw = self.state | 0x0210
                if self.state == ENABLED and cw & 0x10:
                    sw |= 0x1000
                self.set(0x6041, 0, struct.pack("<H", sw))
        elif index == 0x6060:
            self.set(0x6061, 0, bytes(data))
        elif index == 0x1400 and subindex == 1:
            cob = struct.unpack("<I", bytes(data))[0]
            if not cob & 0x80000000:
                self.network.subscribe(cob & 0x7FF, self.on_rpdo)

    def on_nmt(self, can_id, data, timestamp):
        cmd, node = struct.unpack_from("BB", data)
        if node in (0, self.id):
            self.trace({"event": "nmt", "node": self.id, "command": cmd})

    def mapping(self, index):
        return [self.u32(index, s) for s in range(1, self.u8(index, 0) + 1)]

    def on_rpdo(self, can_id, data, timestamp):
        # decode with the mapping machlink wrote to 0x1600
        at = 0
        for word in self.mapping(0x1600):
            index, sub, bits = word >> 16, (word >> 8) & 0xFF, word & 0xFF
            n = bits // 8
            value = bytes(data[at:at + n])
            at += n
            if (index, sub) in ((0x60C1, 1), (0x607A, 0)):
                with self.lock:
                    self.setpoint = struct.unpack("<i", value)[0]
            self.set(index, sub, value)

    def on_sync(self):
        if self.node.nmt.state != "OPERATIONAL":
            return
        with self.lock:
            self.syncs += 1
            if self.state == ENABLED and self.setpoint is not None:
                self.position = self.setpoint
                self.trace({"event": "setpoint", "node": self.id, "sync": self.syncs,
                            "value": self.setpoint})
            self.set(0x6064, 0, struct.pack("<i", self.position))
            self.set(0x60F4, 0, struct.pack("<i", 0))
        cob = self.u32(0x1800, 1)
        if cob & 0x80000000 or self.u8(0x1800, 2) not in range(1, 241):
            return
        payload = b""
        for word in self.mapping(0x1A00):
            index, sub, bits = word >> 16, (word >> 8) & 0xFF, word & 0xFF
            payload += self.node.get_data(index, sub)[: bits // 8]
        self.network.send_message(cob & 0x7FF, payload[:8])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--port", required=True)
    ap.add_argument("--nodes", default="1,2,3")
    ap.add_argument("--trace", required=True)
    ap.add_argument("--stuck", type=int, default=0)
    a = ap.parse_args()
    out = open(a.trace, "w")
    lock = threading.Lock()

    def trace(obj):
        with lock:
            out.write(json.dumps(obj) + "\n")
            out.flush()

    network = canopen.Network()
    network.connect(interface="slcan", channel=a.port, bitrate=1000000, sleep_after_open=0)
    drives = [Drive(network, int(n), trace, int(n) == a.stuck) for n in a.nodes.split(",")]
    network.subscribe(0x080, lambda can_id, data, ts: [d.on_sync() for d in drives])
    print("READY", flush=True)
    try:
        sys.stdin.read()
    finally:
        network.disconnect()


if __name__ == "__main__":
    main()
