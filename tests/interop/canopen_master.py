#!/usr/bin/env python3
"""An independent CANopen master: the python `canopen` package (BaseNode402) over
python-can's `slcan` interface, talking to the project's CiA 402 drive emulator.

It does what a CANopen tool does with an unknown CiA 402 drive: NMT, SDO reads of the
identity, 0x6502 and every PDO record (setup_402_state_machine), heartbeat, the power
state machine to OPERATION ENABLED, homing, a profile-position move with the
set-point handshake, and a fault (target beyond the software limit) with its EMCY and
a fault reset.

Usage: canopen_master.py PORT EDS
Prints one JSON object with what it saw; exits non-zero on any failure.
"""
import json
import sys
import time

import canopen

TIMEOUT_S = 5.0
NODE = 1


def wait(cond, what, timeout=TIMEOUT_S):
    t = time.monotonic() + timeout
    while time.monotonic() < t:
        if cond():
            return
        time.sleep(0.005)
    raise RuntimeError(f"timed out waiting for {what}")


def main():
    port, eds = sys.argv[1], sys.argv[2]
    out = {}
    network = canopen.Network()
    network.connect(interface="slcan", channel=port, bitrate=1000000, sleep_after_open=0.1)
    try:
        node = canopen.BaseNode402(NODE, eds)
        network.add_node(node)
        node.nmt.state = "PRE-OPERATIONAL"
        node.sdo[0x1017].raw = 50
        out["heartbeat_state"] = node.nmt.wait_for_heartbeat(timeout=2)
        out["device_type"] = node.sdo[0x1000].raw
        out["name"] = node.sdo[0x1008].raw
        out["supported_modes"] = node.sdo[0x6502].raw
        out["identity_product"] = node.sdo[0x1018][2].raw
        try:
            node.sdo[0x6041].raw = 0
            out["write_ro"] = "accepted"
        except canopen.SdoAbortedError as e:
            out["write_ro"] = e.code
        node.setup_402_state_machine()
        out["tpdo1"] = [f"{v.index:04X}" for v in node.tpdo[1].map]
        out["tpdo2"] = [f"{v.index:04X}" for v in node.tpdo[2].map]
        out["rpdo1"] = [f"{v.index:04X}" for v in node.rpdo[1].map]
        out["rpdo2"] = [f"{v.index:04X}" for v in node.rpdo[2].map]
        out["tpdo2_inhibit"] = node.tpdo[2].inhibit_time
        node.nmt.state = "OPERATIONAL"
        wait(lambda: node.nmt.state == "OPERATIONAL", "OPERATIONAL heartbeat")
        node.state = "SWITCHED ON"
        node.state = "OPERATION ENABLED"
        out["state"] = node.state
        out["homed"] = node.homing(timeout=5)
        node.op_mode = "PROFILED POSITION"
        out["op_mode"] = node.op_mode
        node.sdo[0x6081].raw = 100000

        rpdo = node.rpdo[2]
        status = node.tpdo[2]

        def move(target):
            rpdo["Target position"].raw = target
            rpdo["Controlword"].raw = 0x0F
            rpdo.transmit()
            rpdo["Controlword"].raw = 0x1F
            rpdo.transmit()
            wait(lambda: node.statusword & 0x1000, "set-point acknowledge")
            rpdo["Controlword"].raw = 0x0F
            rpdo.transmit()

        move(20000)
        wait(lambda: status["Statusword"].raw & 0x0400 and status["Position actual value"].raw == 20000,
             "target reached at 20000")
        out["position"] = node.sdo[0x6064].raw
        out["statusword_after_move"] = node.statusword

        # Past the software limit (0x607D:2): the drive faults and says why.
        emcy = []
        node.emcy.add_callback(lambda e: emcy.append(e.code))
        rpdo["Target position"].raw = 10_000_000
        rpdo["Controlword"].raw = 0x1F
        rpdo.transmit()
        wait(lambda: node.state == "FAULT", "FAULT")
        wait(lambda: emcy, "an EMCY")
        out["fault_emcy"] = emcy[0]
        out["error_code"] = node.sdo[0x603F].raw
        rpdo["Controlword"].raw = 0x0F
        rpdo.transmit()
        node.reset_from_fault()
        out["after_reset"] = node.state
        wait(lambda: len(emcy) >= 2, "the error-reset EMCY")
        out["reset_emcy"] = emcy[1]
        node.nmt.state = "PRE-OPERATIONAL"
        out["ok"] = True
    finally:
        network.disconnect()
    print(json.dumps(out))


if __name__ == "__main__":
    try:
        main()
    except Exception as e:  # noqa: BLE001 - report any failure as JSON
        print(json.dumps({"ok": False, "error": f"{type(e).__name__}: {e}"}))
        sys.exit(1)
