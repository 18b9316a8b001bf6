"""A plant consumer of the bridge's JSON topics (tests/tests/bridge_mqtt.rs).

mqtt_consumer.py HOST PORT TOPIC COUNT: subscribes (QoS 1), prints READY
once the broker confirmed the subscription, then `SEQ <stream> <seq>` for
each of COUNT envelopes, then DONE.
"""

import json
import sys

import paho.mqtt.client as mqtt

host, port, topic, count = sys.argv[1], int(sys.argv[2]), sys.argv[3], int(sys.argv[4])
seen = 0


def on_connect(client, userdata, flags, reason_code, properties):
    client.subscribe(topic, qos=1)


def on_subscribe(client, userdata, mid, reason_codes, properties):
    print("READY", flush=True)


def on_message(client, userdata, msg):
    global seen
    env = json.loads(msg.payload)
    # proto3 JSON: 64-bit integers are strings.
    print("SEQ", env["stream"], int(env["seq"]), flush=True)
    seen += 1
    if seen == count:
        print("DONE", flush=True)
        client.disconnect()


client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
client.on_connect = on_connect
client.on_subscribe = on_subscribe
client.on_message = on_message
client.connect(host, port)
client.loop_forever()
