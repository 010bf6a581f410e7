#!/usr/bin/env python3
"""An independent Sparkplug B plant for the northbound's interop test.

paho-mqtt subscribes to spBv1.0/<group>/#; each payload is decoded with the
specification's sparkplug_b.proto (beside this file), compiled at start by grpcio-tools'
protoc into a temporary folder, the way Eclipse Tahu's Python clients use it. Nothing of
the gateway's code is involved. Output, one JSON object per line on stdout:
  {"subscribed": true}                      once the broker acknowledged the subscription
  {"topic": ..., "payload": {...}}          per message (protobuf's JSON mapping with the
                                            .proto field names; 64-bit integers as strings)
It exits after the first message whose topic contains --until.
"""

import argparse
import json
import os
import sys
import tempfile

import paho.mqtt.client as mqtt
from google.protobuf.json_format import MessageToDict
from grpc_tools import protoc


def compile_proto():
    here = os.path.dirname(os.path.abspath(__file__))
    out = tempfile.mkdtemp(prefix="sparkplug-pb2-")
    include = os.path.join(os.path.dirname(protoc.__file__), "_proto")
    rc = protoc.main(["protoc", f"-I{here}", f"-I{include}", f"--python_out={out}", "sparkplug_b.proto"])
    if rc != 0:
        sys.exit(f"protoc failed ({rc}) on {here}/sparkplug_b.proto")
    sys.path.insert(0, out)
    import sparkplug_b_pb2  # noqa: E402 (generated just above)

    return sparkplug_b_pb2


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--port", type=int, required=True)
    ap.add_argument("--group", required=True)
    ap.add_argument("--until", required=True)
    args = ap.parse_args()
    pb = compile_proto()

    def emit(obj):
        print(json.dumps(obj), flush=True)

    def on_connect(client, userdata, flags, reason, properties):
        client.subscribe(f"spBv1.0/{args.group}/#", qos=1)

    def on_subscribe(client, userdata, mid, reasons, properties):
        emit({"subscribed": True})

    def on_message(client, userdata, msg):
        payload = pb.Payload()
        payload.ParseFromString(msg.payload)
        emit({"topic": msg.topic, "payload": MessageToDict(payload, preserving_proto_field_name=True)})
        if args.until in msg.topic:
            client.disconnect()

    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"independent-plant-{os.getpid()}")
    client.on_connect = on_connect
    client.on_subscribe = on_subscribe
    client.on_message = on_message
    client.connect("127.0.0.1", args.port, keepalive=30)
    client.loop_forever(retry_first_connection=True)


if __name__ == "__main__":
    main()
