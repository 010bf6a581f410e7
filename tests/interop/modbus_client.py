"""An independent Modbus client (pymodbus) driving the project's drive emulator the way
a PLC or SCADA would: by the register map of a drive profile, over TCP or RTU.

usage: modbus_client.py (--tcp HOST:PORT | --rtu PATH) --profile FILE --units 1,2

Homes the first unit, moves every unit to a target, polls the status word until the
move ends, reads the actual positions, and provokes the three exceptions (illegal
function, address, value). Prints one JSON object."""

import argparse
import json
import sys

from pymodbus.client import ModbusSerialClient, ModbusTcpClient

from modbus_profile import Profile


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--tcp")
    ap.add_argument("--rtu")
    ap.add_argument("--profile", required=True)
    ap.add_argument("--units", default="1,2")
    a = ap.parse_args()
    p = Profile(a.profile)
    units = [int(u) for u in a.units.split(",")]
    if a.tcp:
        host, port = a.tcp.rsplit(":", 1)
        client = ModbusTcpClient(host, port=int(port), timeout=2, retries=0)
    else:
        client = ModbusSerialClient(a.rtu, baudrate=115200, parity="N", timeout=2, retries=0)
    if not client.connect():
        print(json.dumps({"error": "cannot connect"}))
        return 1

    def read(reg, unit):
        fn = client.read_input_registers if reg.table == "input" else client.read_holding_registers
        r = fn(reg.address, count=reg.words, device_id=unit)
        if r.isError():
            raise RuntimeError(f"read {reg.key} of unit {unit}: {r}")
        return reg.decode(r.registers)

    def write(reg, value, unit):
        words = reg.encode(value)
        if len(words) == 1:
            r = client.write_register(reg.address, words[0], device_id=unit)
        else:
            r = client.write_registers(reg.address, words, device_id=unit)
        if r.isError():
            raise RuntimeError(f"write {reg.key} of unit {unit}: {r}")

    def command(name, unit):
        reg, value, release = p.commands[name]
        write(reg, value, unit)
        if release is not None:
            write(reg, release, unit)

    def wait(unit, until_homed=False):
        for polls in range(1, 10001):
            st = read(p.status, unit)
            if st & p.bits["alarm"]:
                raise RuntimeError(f"unit {unit} alarm, status 0x{st:04X}")
            busy = (st & p.bits["busy"]) != 0 if p.bits["busy"] else (st & p.bits["in_position"]) == 0
            homed = (st & p.bits["home_done"]) != 0 if p.bits["home_done"] else True
            if not busy and (homed or not until_homed):
                return polls
        raise RuntimeError("motion did not end")

    out = {"units": {}}
    # Each unit is a drive of its own: each homes its own axis.
    for u in units:
        command("home", u)
        polls = wait(u, until_homed=True)
        out.setdefault("home_polls", polls)
    targets = {u: 25.0 + 30.0 * i for i, u in enumerate(units)}
    for u in units:
        words = p.move_words(targets[u], 50.0)
        r = client.write_registers(p.block_start, words, device_id=u)
        if r.isError():
            raise RuntimeError(f"move block of unit {u}: {r}")
    for u in units:
        polls = wait(u)
        counts = read(p.actual, u)
        out["units"][str(u)] = {"target_counts": round(targets[u] * p.counts_per_mm), "actual_counts": counts, "polls": polls}
    # Exceptions: an address outside the map, a function drives do not have, a value
    # the trigger register does not take.
    r = client.read_holding_registers(0x7FF0, count=1, device_id=units[0])
    out["unmapped_read"] = r.exception_code if r.isError() else None
    r = client.read_coils(0, count=1, device_id=units[0])
    out["read_coils"] = r.exception_code if r.isError() else None
    r = client.write_register(p.trigger.address, 7, device_id=units[0]) if p.trigger.words == 1 else \
        client.write_registers(p.trigger.address, [0, 7], device_id=units[0])
    out["bad_trigger"] = r.exception_code if r.isError() else None
    client.close()
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
