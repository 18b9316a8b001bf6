#!/usr/bin/env python3
"""The cangate package's torque streams (``stream_setpoints(...,
torques=True)``) against a gateway with a simulated drive in cyclic
synchronous torque (axis T, max_torque 300, torque_slope 2000).

Run by tests/tests/python_package.rs: ``python torque_stream.py`` with
CANGATE_SERVER set. Prints ``torque stream: all checks passed`` at the
end; any failed check raises (non-zero exit).
"""

import cangate


def expect(cond, what):
    if not cond:
        raise AssertionError(what)


def push():
    """Up to 30 per mille at 1000 per mille/s, held, back to 0 at 0.5 s:
    one point per ms, in batches of 50."""
    for k0 in range(0, 601, 50):
        yield [
            (k * 1000, [max(0.0, min(k, 30.0, 500.0 - k))])
            for k in range(k0, min(k0 + 50, 601))
        ]


def main():
    with cangate.Client(timeout=10.0) as c:
        with c.control("T", name="python torque test") as ax:
            ax.enable("T", wait=True)
            statuses = list(ax.stream_setpoints(push(), depth_ms=100, status_period_ms=20, torques=True))
            last = statuses[-1]
            expect(last.ended == "CLIENT_ENDED", last)
            expect(last.counters.received == 601 and last.counters.refused == 0, last.counters)
            expect(list(last.commanded_torques) == [0.0], last)
            peak = max(s.commanded_torques[0] for s in statuses if s.commanded_torques)
            expect(abs(peak - 30.0) < 1e-6, peak)
        print(f"ok torque stream: {last.counters.played} points played, peak {peak:.1f} per mille")
    print("torque stream: all checks passed", flush=True)


if __name__ == "__main__":
    main()
