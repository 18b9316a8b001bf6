"""A plant consumer of the bridge's JSON subjects on NATS JetStream
(tests/tests/bridge_nats.rs).

nats_consumer.py HOST PORT SUBJECT COUNT: reads SUBJECT from the start of
the JetStream stream that keeps it (an ordered consumer), prints
`SEQ <stream> <seq>` for each of COUNT envelopes, then DONE.
"""

import asyncio
import json
import sys

import nats

host, port, subject, count = sys.argv[1], int(sys.argv[2]), sys.argv[3], int(sys.argv[4])


async def main():
    nc = await nats.connect(f"nats://{host}:{port}")
    js = nc.jetstream()
    sub = await js.subscribe(subject, ordered_consumer=True)
    seen = 0
    async for msg in sub.messages:
        env = json.loads(msg.data)
        # proto3 JSON: 64-bit integers are strings.
        print("SEQ", env["stream"], int(env["seq"]), flush=True)
        seen += 1
        if seen == count:
            break
    print("DONE", flush=True)
    await nc.close()


asyncio.run(main())
