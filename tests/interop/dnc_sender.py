#!/usr/bin/env python3
"""An independent DNC sender (what a shop's DNC software does on its RS-232 port),
written against the controllers' public description of the protocol (docs/dnc.md):
wait for DC1, send the tape line by line, stop at DC3 until DC1, end on NAK (the
controller's alarm) or SYN (reset).

It makes a pseudo-terminal of its own, prints the path of its far end (where the
gateway opens its port) on the first line of standard output, then sends, and keeps its
end open until the far end closes.

Usage: dnc_sender.py TAPE_FILE
Prints one JSON object with what it saw: {"ok", "sent_lines", "pauses", "alarm"}.
"""
import json
import os
import select
import sys
import tty

DC1, DC3, NAK, SYN = 0x11, 0x13, 0x15, 0x16
TIMEOUT_S = 120.0


def main():
    lines = open(sys.argv[1], "rb").read().split(b"\n")
    if lines and lines[-1] == b"":
        lines.pop()
    master, slave = os.openpty()
    tty.setraw(master)
    print(os.ttyname(slave), flush=True)
    state = {"reading": False, "pauses": 0, "alarm": None}

    def take(block):
        # Flow-control codes from the far end: wait `block` seconds for them. False once
        # the far end has closed its port.
        r, _, _ = select.select([master], [], [], block)
        if not r:
            return True
        try:
            got = os.read(master, 256)
        except OSError:
            return False
        for b in got:
            if b == DC1:
                state["reading"] = True
            elif b == DC3:
                if state["reading"]:
                    state["pauses"] += 1
                state["reading"] = False
            elif b in (NAK, SYN):
                state["alarm"] = "NAK" if b == NAK else "SYN"
        return True

    def wait_dc1():
        waited = 0.0
        while not state["reading"] and state["alarm"] is None:
            take(0.05)
            waited += 0.05
            if waited > TIMEOUT_S:
                print(json.dumps({"ok": False, "error": "no DC1"}))
                sys.exit(1)

    wait_dc1()
    # The far end has opened its port: from here on, it alone holds it open (a real line
    # keeps what was sent on it; a pseudo-terminal drops what its far end has not read
    # once the last holder of this end closes).
    os.close(slave)
    sent = 0
    for line in lines:
        data = line + b"\n"
        at = 0
        while at < len(data):
            take(0)
            wait_dc1()
            if state["alarm"]:
                break
            os.write(master, data[at : at + 8])
            at += 8
        if state["alarm"]:
            break
        sent += 1
    # Keep the port open, as DNC software does, until the far end closes its own (a NAK
    # for the last characters may come meanwhile).
    waited = 0.0
    while take(0.1) and waited < TIMEOUT_S:
        waited += 0.1
    print(json.dumps({"ok": state["alarm"] is None, "sent_lines": sent,
                      "pauses": state["pauses"], "alarm": state["alarm"]}))


if __name__ == "__main__":
    main()
