#!/usr/bin/env python3
"""A motion-block device written with pymodbus, serving machlink's Modbus register map
(docs/modbus.md) on TCP or RTU, so the Rust link is checked against an implementation we
did not write. Blocks are executed at once when the write sequence advances; every executed
block is appended to the trace file as one JSON object per line.

    python3 tests/python/modbus_device.py --tcp PORT --trace FILE
    python3 tests/python/modbus_device.py --rtu /dev/pts/N --trace FILE

Prints READY on stdout once it serves.
"""

import argparse
import asyncio
import json
import sys

try:
    from pymodbus.constants import ExcCodes
    from pymodbus.server import ModbusSerialServer, ModbusTcpServer
    from pymodbus.simulator import DataType, SimData, SimDevice
except ImportError as e:  # pragma: no cover
    print(f"pymodbus is missing ({e}): run .ci/run or pip install -r .ci/requirements.txt",
          file=sys.stderr)
    sys.exit(3)

# Header register offsets (docs/modbus.md).
VERSION, CAPACITY, BLOCK_SIZE, STATE, FAULT, COMMAND = 0, 1, 2, 3, 4, 5
WRITE_SEQ, CONSUMED_SEQ, POS = 6, 8, 10
RING, BLOCK = 32, 16
IDLE, RUNNING, HOLD, FAULTED = 0, 1, 2, 3
START, HOLD_CMD, RESUME, STOP, CLEAR_FAULT, SYNC = 1, 2, 3, 4, 5, 6
END, TOOL_CHANGE = 6, 7
SEQUENCE_FAULT, BAD_BLOCK_FAULT = 1, 2


class Device:
    """The map's behaviour on top of pymodbus's register list."""

    def __init__(self, capacity, high_first, trace):
        self.capacity = capacity
        self.high_first = high_first
        self.trace = trace
        # the tool change block the device held at (rule 10a): after the resume it runs
        self.tool_stop = None

    def get32(self, regs, at):
        a, b = regs[at], regs[at + 1]
        return (a << 16 | b) if self.high_first else (b << 16 | a)

    def put32(self, regs, at, v):
        v &= 0xFFFFFFFF
        hi, lo = v >> 16, v & 0xFFFF
        regs[at:at + 2] = [hi, lo] if self.high_first else [lo, hi]

    def signed(self, v):
        return v - (1 << 32) if v & 0x80000000 else v

    def slot_at(self, seq):
        return RING + ((seq - 1) % self.capacity) * BLOCK

    async def action(self, _fc, start, address, count, regs, values):
        if values is None:
            return None
        off, end = address - start, address - start + count
        consumed, write = self.get32(regs, CONSUMED_SEQ), self.get32(regs, WRITE_SEQ)
        if off >= RING:
            for seq in range(consumed + 1, min(write, consumed + self.capacity) + 1):
                s = self.slot_at(seq)
                if off < s + BLOCK and s < end:
                    return ExcCodes.ILLEGAL_VALUE
            return None
        if end > RING or any(a not in (COMMAND, WRITE_SEQ, WRITE_SEQ + 1) for a in range(off, end)):
            return ExcCodes.ILLEGAL_ADDRESS
        touches_seq = off <= WRITE_SEQ + 1 and end > WRITE_SEQ
        if touches_seq:
            if not (off <= WRITE_SEQ and end >= WRITE_SEQ + 2):
                return ExcCodes.ILLEGAL_VALUE
            i = WRITE_SEQ - off
            new = self.get32(values, i)
            if new > consumed + self.capacity or (regs[STATE] != IDLE and new < write):
                return ExcCodes.ILLEGAL_VALUE
            self.put32(regs, WRITE_SEQ, new)
        if off <= COMMAND < end:
            err = self.command(regs, values[COMMAND - off])
            if err:
                return err
            values[COMMAND - off] = 0  # the command register reads back 0 once acted on
            if touches_seq:  # keep what the command did to the write sequence
                values[WRITE_SEQ - off:WRITE_SEQ - off + 2] = regs[WRITE_SEQ:WRITE_SEQ + 2]
        self.run(regs)
        return None

    def command(self, regs, c):
        state = regs[STATE]
        if c == 0:
            return None
        if c == START:
            if state == FAULTED:
                return ExcCodes.DEVICE_FAILURE
            if state == IDLE:
                regs[STATE] = RUNNING
        elif c == HOLD_CMD:
            if state == RUNNING:
                regs[STATE] = HOLD
        elif c == RESUME:
            if state == HOLD:
                regs[STATE] = RUNNING
        elif c == STOP:
            self.tool_stop = None
            if state != FAULTED:
                regs[STATE] = IDLE
                self.put32(regs, WRITE_SEQ, self.get32(regs, CONSUMED_SEQ))
        elif c == CLEAR_FAULT:
            if state == FAULTED:
                regs[STATE], regs[FAULT] = IDLE, 0
                self.put32(regs, WRITE_SEQ, self.get32(regs, CONSUMED_SEQ))
        elif c == SYNC:
            if state != IDLE:
                return ExcCodes.ILLEGAL_VALUE
            self.tool_stop = None
            self.put32(regs, CONSUMED_SEQ, self.get32(regs, WRITE_SEQ))
        else:
            return ExcCodes.ILLEGAL_VALUE
        return None

    def run(self, regs):
        """Executes every committed block at once (an infinitely fast machine)."""
        while regs[STATE] == RUNNING:
            consumed, write = self.get32(regs, CONSUMED_SEQ), self.get32(regs, WRITE_SEQ)
            if consumed >= write:
                break
            seq = consumed + 1
            b = self.slot_at(seq)
            kind = regs[b + 2]
            if self.get32(regs, b) != seq:
                regs[STATE], regs[FAULT] = FAULTED, SEQUENCE_FAULT
                break
            if not 1 <= kind <= 7:
                regs[STATE], regs[FAULT] = FAULTED, BAD_BLOCK_FAULT
                break
            if kind == TOOL_CHANGE and self.tool_stop != seq:
                # hold here, the block unfinished, until the operator resumes (rule 10a)
                self.tool_stop = seq
                regs[STATE] = HOLD
                break
            rec = {
                "seq": seq,
                "kind": kind,
                "target": [self.signed(self.get32(regs, b + k)) for k in (4, 6, 8)],
                "feed": self.get32(regs, b + 10),
                "center": [self.signed(self.get32(regs, b + k)) for k in (12, 14)],
            }
            self.trace.write(json.dumps(rec) + "\n")
            for axis, v in enumerate(rec["target"]):
                self.put32(regs, POS + 2 * axis, v)
            self.put32(regs, CONSUMED_SEQ, seq)
            if kind == END:
                regs[STATE] = IDLE
        self.trace.flush()


async def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    where = ap.add_mutually_exclusive_group(required=True)
    where.add_argument("--tcp", type=int, metavar="PORT", help="serve Modbus TCP on 127.0.0.1:PORT")
    where.add_argument("--rtu", metavar="PTY", help="serve Modbus RTU on this serial port / pty")
    ap.add_argument("--trace", required=True, help="file to append executed blocks to (JSON lines)")
    ap.add_argument("--unit", type=int, default=1, help="unit id")
    ap.add_argument("--base", type=int, default=0, help="address of header register 0")
    ap.add_argument("--capacity", type=int, default=32, help="ring capacity in blocks")
    ap.add_argument("--word-order", choices=["high-first", "low-first"], default="high-first")
    args = ap.parse_args()

    with open(args.trace, "w", encoding="utf-8") as trace:
        dev = Device(args.capacity, args.word_order == "high-first", trace)
        regs = [0] * (RING + args.capacity * BLOCK)
        regs[VERSION], regs[CAPACITY], regs[BLOCK_SIZE] = 1, args.capacity, BLOCK
        device = SimDevice(
            id=args.unit,
            simdata=[SimData(args.base, values=regs, datatype=DataType.REGISTERS)],
            action=dev.action,
        )
        if args.tcp is not None:
            server = ModbusTcpServer(device, address=("127.0.0.1", args.tcp))
        else:
            server = ModbusSerialServer(device, port=args.rtu, baudrate=115200)
        await server.serve_forever(background=True)
        print("READY", flush=True)
        await asyncio.Event().wait()


if __name__ == "__main__":
    try:
        asyncio.run(main())
    except KeyboardInterrupt:
        pass
