#!/usr/bin/env python3
"""An independent CANopen slave: a python `canopen` LocalNode (SDO server, NMT slave,
heartbeat from 0x1017, EMCY producer) built from an EDS, on python-can's `slcan`
interface. The gateway's CANopen driver is the master on the same bus.

Writing 0xEEEE to the controlword makes it send EMCY 0x8611 (a test hook; a LocalNode
has no drive behind it).

Usage: canopen_localnode.py PORT EDS NODE_ID
Prints `ready` when it serves, then serves until stdin closes (or 60 s).
"""
import select
import sys
import time

import canopen


def main():
    port, eds, node_id = sys.argv[1], sys.argv[2], int(sys.argv[3])
    network = canopen.Network()
    network.connect(interface="slcan", channel=port, bitrate=1000000, sleep_after_open=0.1)
    node = canopen.LocalNode(node_id, eds)
    network.add_node(node)

    def hook(index, subindex, od, data):
        if index == 0x6040 and int.from_bytes(data, "little") == 0xEEEE:
            node.emcy.send(0x8611, 0x21)

    node.add_write_callback(hook)
    node.nmt.state = "PRE-OPERATIONAL"
    print("ready", flush=True)
    end = time.monotonic() + 60
    while time.monotonic() < end:
        r, _, _ = select.select([sys.stdin], [], [], 0.1)
        if r and not sys.stdin.read(1):
            break
    network.disconnect()


if __name__ == "__main__":
    main()
