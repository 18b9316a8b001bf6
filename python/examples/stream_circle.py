#!/usr/bin/env python3
"""Streams a circle on two cyclic axes at 1 kHz (``Axes.StreamSetpoints``)
from this process, optionally through injected network jitter, and reports
the contour error: how far the positions the gateway commanded lie from the
circle (radial error, max and RMS). The Python twin of
``client/examples/stream_circle.rs``.

    cargo run -p cangate-server &          # the demo on 127.0.0.1:50051
    python python/examples/stream_circle.py --jitter-ms 5

Options: ``--server URL`` (default CANGATE_SERVER, else
http://127.0.0.1:50051), ``--axes X,Y``, ``--radius MM`` (10), ``--turns N``
(2), ``--period-s S`` (one turn at full speed, 1), ``--depth-ms MS`` (jitter
buffer, 50), ``--jitter-ms MS`` (p99 of the delay added to each point,
exponentially distributed, order kept; 0), ``--seed N``.

The angular speed ramps up over half a turn's time and down likewise, so
the circle starts and ends at rest where the axes stand (its leftmost
point is their start). The generator below makes each point when its time
comes (1 ms apart), holds it back by its injected delay (never overtaking
an earlier one: TCP keeps the order) and hands over the points that are
due together; gRPC iterates it in its own thread, so it may sleep.
"""

import argparse
import math
import random
import sys
import time

import cangate
from cangate.v1 import axes_pb2


class Circle:
    """The path: a circle through `start` (its leftmost point), run
    counter-clockwise with the angular speed ramped up and down."""

    def __init__(self, start, radius, turns, period):
        self.centre = (start[0] + radius, start[1])
        self.radius = radius
        self.turns = max(turns, 0.5)
        self.period = period

    def duration(self):
        return self.turns * self.period + self.period / 2.0

    def angle(self, s):
        w = 2.0 * math.pi / self.period
        ramp = self.period / 2.0
        cruise = self.turns * self.period - ramp
        if s <= 0.0:
            return 0.0
        if s < ramp:
            return w * s * s / (2.0 * ramp)
        if s < ramp + cruise:
            return w * ramp / 2.0 + w * (s - ramp)
        r = max(2.0 * ramp + cruise - s, 0.0)
        return w * (ramp / 2.0 + cruise + ramp / 2.0) - w * r * r / (2.0 * ramp)

    def point(self, s):
        a = self.angle(s)
        return (self.centre[0] - self.radius * math.cos(a), self.centre[1] + self.radius * math.sin(a))

    def radial_error(self, p):
        return math.hypot(p[0] - self.centre[0], p[1] - self.centre[1]) - self.radius


def paced_points(circle, jitter_ms, seed):
    """Batches of ``(t_us, [x, y])``, each yielded when its points are due
    after their injected delay."""
    rng = random.Random(seed)
    # Exponential delays whose 99th percentile is `jitter_ms`.
    mean_s = jitter_ms / 1000.0 / math.log(100.0) if jitter_ms > 0 else 0.0
    # One point per ms, and the path's end.
    times = [k / 1000.0 for k in range(int(circle.duration() * 1000.0) + 1)]
    if times[-1] < circle.duration():
        times.append(circle.duration())
    started = time.monotonic()
    release = 0.0
    batch = []
    for t in times:
        # Released after its time plus its delay, never before the previous.
        delay = rng.expovariate(1.0 / mean_s) if mean_s > 0 else 0.0
        due = max(t + delay, release)
        wait = started + due - time.monotonic()
        if wait > 0 and batch:
            yield batch
            batch = []
        if wait > 0:
            time.sleep(wait)
        release = due
        batch.append((int(t * 1e6), list(circle.point(t))))
    if batch:
        yield batch


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--server", default=None)
    parser.add_argument("--axes", default="X,Y")
    parser.add_argument("--radius", type=float, default=10.0)
    parser.add_argument("--turns", type=float, default=2.0)
    parser.add_argument("--period-s", type=float, default=1.0)
    parser.add_argument("--depth-ms", type=int, default=50)
    parser.add_argument("--jitter-ms", type=float, default=0.0)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)
    names = args.axes.split(",")
    if len(names) != 2:
        parser.error("--axes names two axes")

    with cangate.Client(args.server, timeout=10.0) as c:
        with c.control(*names, name="stream_circle.py") as lease:
            for name in names:
                lease.enable(name, wait=True)
            start = [c.get_axis(name).status.position for name in names]
            circle = Circle(start, args.radius, args.turns, args.period_s)
            statuses = list(
                lease.stream_setpoints(
                    paced_points(circle, args.jitter_ms, args.seed),
                    names,
                    depth_ms=args.depth_ms,
                    status_period_ms=10,
                )
            )
    last = statuses[-1]
    n = last.counters
    print(
        f"circle r={args.radius} on {','.join(names)}, jitter p99 {args.jitter_ms} ms, "
        f"buffer {args.depth_ms} ms: ended {last.ended}"
    )
    print(
        f"points received {n.received}, played {n.played}, refused {n.refused}, "
        f"late {n.late}, dropped {n.dropped}, underruns {n.underruns}"
    )
    # Sampled at each status while the stream played.
    playing = [s for s in statuses if s.state == axes_pb2.SETPOINT_STREAM_PLAYING]
    for what, field in (("commanded", "commanded_positions"), ("actual", "actual_positions")):
        errors = [circle.radial_error(getattr(s, field)) for s in playing if len(getattr(s, field)) == 2]
        if errors:
            worst = max(abs(e) for e in errors)
            rms = math.sqrt(sum(e * e for e in errors) / len(errors))
            print(f"contour error, {what} positions: max {worst:.4f}, RMS {rms:.4f} ({len(errors)} samples)")
    return 0 if last.ended == "CLIENT_ENDED" and n.refused == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
