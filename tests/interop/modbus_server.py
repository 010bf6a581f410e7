"""An independent Modbus TCP server (pymodbus) configured from a drive profile's
register map, with a minimal drive behind it, for the project's driver to drive.

usage: modbus_server.py --profile FILE --units 1,2

Prints `listening PORT` once it accepts connections, then serves until killed. On a
trigger write the unit's actual position jumps to the target and the unit reports busy
for one status read; commands act on their rising edge (profiles with `release`) or on
each write of their value. The triggers counted per unit are printed on stderr at each
move (`trigger UNIT N`)."""

import argparse
import asyncio
import socket
import sys
from functools import partial

from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from modbus_profile import Profile


class Drive:
    def __init__(self, unit):
        self.unit = unit
        self.counts = 0
        self.busy_reads = 0
        self.homed = False
        self.triggers = 0


def covers(reg, address, count):
    return reg.address >= address and reg.address + reg.words <= address + count


def words_of(reg, regs, start):
    at = reg.address - start
    return regs[at:at + reg.words]


async def action(p, drive, fc, start, address, count, regs, values):
    if values is not None:
        new = list(regs)
        new[address - start:address - start + count] = values
        old = regs
        if covers(p.trigger, address, count):
            v = p.trigger.decode(words_of(p.trigger, new, start))
            if v not in (0, p.trigger_value):
                return ExcCodes.ILLEGAL_VALUE
            if v == p.trigger_value:
                drive.counts = p.position.decode(words_of(p.position, new, start))
                drive.busy_reads = 1
                drive.triggers += 1
                print(f"trigger {drive.unit} {drive.triggers}", file=sys.stderr, flush=True)
        for name, (reg, value, release) in p.commands.items():
            if not covers(reg, address, count):
                continue
            nv = reg.decode(words_of(reg, new, start))
            ov = reg.decode(words_of(reg, old, start))
            acts = ((nv & ~ov) & value) == value if release is not None else nv == value
            if not acts:
                continue
            if name == "home":
                drive.counts, drive.homed, drive.busy_reads = 0, True, 1
            elif name == "stop":
                drive.busy_reads = 0
        return None
    # A read: fill the live registers in place.
    if covers(p.status, address, count) or covers(p.actual, address, count):
        busy = drive.busy_reads > 0
        st = 0
        b = p.bits
        if b["ready"] and not busy:
            st |= b["ready"]
        if b["busy"] and busy:
            st |= b["busy"]
        if b["in_position"] and not busy:
            st |= b["in_position"]
        if b["home_done"] and drive.homed:
            st |= b["home_done"]
        for reg, v in ((p.status, st), (p.actual, drive.counts)):
            at = reg.address - start
            regs[at:at + reg.words] = reg.encode(v)
        if p.alarm_code is not None:
            at = p.alarm_code.address - start
            regs[at:at + p.alarm_code.words] = [0] * p.alarm_code.words
        if covers(p.status, address, count) and drive.busy_reads > 0:
            drive.busy_reads -= 1
    return None


def device(p, unit):
    regs = {}
    for r in p.block + [p.actual, p.status] + [c[0] for c in p.commands.values()]:
        regs[r.address] = r.words
    if p.alarm_code is not None:
        regs[p.alarm_code.address] = p.alarm_code.words
    data = [SimData(a, values=[0] * n, datatype=DataType.REGISTERS) for a, n in sorted(regs.items())]
    return SimDevice(unit, simdata=data, action=partial(action, p, Drive(unit)))


async def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--profile", required=True)
    ap.add_argument("--units", default="1,2")
    a = ap.parse_args()
    p = Profile(a.profile)
    devices = [device(p, int(u)) for u in a.units.split(",")]
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    server = ModbusTcpServer(devices, address=("127.0.0.1", port))
    await server.serve_forever(background=True)
    print(f"listening {port}", flush=True)
    await asyncio.Event().wait()


if __name__ == "__main__":
    asyncio.run(main())
