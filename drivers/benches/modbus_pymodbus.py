"""The Modbus benchmark's work done by pymodbus: read 4 input registers at 0x0020 of
unit 1, one request after the other per connection, against the same emulator.

usage: modbus_pymodbus.py (--tcp HOST:PORT [--connections K] | --rtu PATH) -n N
prints: tx_per_s p50_us p90_us p99_us"""

import argparse
import asyncio
import time

from pymodbus.client import AsyncModbusTcpClient, ModbusSerialClient, ModbusTcpClient


def pct(sorted_lat, p):
    return sorted_lat[round((len(sorted_lat) - 1) * p)]


def sync_run(client, n):
    lat = []
    for _ in range(n):
        t = time.perf_counter()
        r = client.read_input_registers(0x20, count=4, device_id=1)
        lat.append((time.perf_counter() - t) * 1e6)
        assert not r.isError() and len(r.registers) == 4
    return lat


async def async_conn(host, port, n, lat):
    c = AsyncModbusTcpClient(host, port=port, timeout=2, retries=0)
    await c.connect()
    for _ in range(n):
        t = time.perf_counter()
        r = await c.read_input_registers(0x20, count=4, device_id=1)
        lat.append((time.perf_counter() - t) * 1e6)
        assert not r.isError()
    c.close()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--tcp")
    ap.add_argument("--rtu")
    ap.add_argument("-n", type=int, default=2000)
    ap.add_argument("--connections", type=int, default=1)
    a = ap.parse_args()
    if a.rtu:
        c = ModbusSerialClient(a.rtu, baudrate=115200, parity="N", timeout=2, retries=0)
        c.connect()
        sync_run(c, 100)
        t0 = time.perf_counter()
        lat = sync_run(c, a.n)
        wall = time.perf_counter() - t0
        c.close()
    else:
        host, port = a.tcp.rsplit(":", 1)
        if a.connections == 1:
            c = ModbusTcpClient(host, port=int(port), timeout=2, retries=0)
            c.connect()
            sync_run(c, 100)
            t0 = time.perf_counter()
            lat = sync_run(c, a.n)
            wall = time.perf_counter() - t0
            c.close()
        else:
            lat = []

            async def all_conns():
                await asyncio.gather(*(async_conn(host, int(port), a.n, lat) for _ in range(a.connections)))

            t0 = time.perf_counter()
            asyncio.run(all_conns())
            wall = time.perf_counter() - t0
    lat.sort()
    print(f"{len(lat) / wall:.1f} {pct(lat, 0.5):.1f} {pct(lat, 0.9):.1f} {pct(lat, 0.99):.1f}")


if __name__ == "__main__":
    main()
