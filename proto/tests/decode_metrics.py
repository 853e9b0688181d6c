#!/usr/bin/env python3
"""Decode an fsrl Metrics message with the PyPI `msgpack` package and check fields by name.

Usage: python3 proto/tests/decode_metrics.py FILE

FILE holds one encoded `proto::Message<Metrics>` as written by the Rust test
`python::metrics_are_readable_from_python` (values from `proto::fixtures::metrics`).
Exit status 0 on success; 2 if `msgpack` is missing; 1 on a mismatch.
"""
import sys

try:
    import msgpack
except ImportError:
    sys.stderr.write("python module `msgpack` missing: pip install msgpack\n")
    sys.exit(2)


def main(path):
    with open(path, "rb") as f:
        msg = msgpack.unpackb(f.read(), raw=False)
    header, body = msg["header"], msg["body"]
    assert header["protocol_version"] == 1, header
    assert header["kind"] == "metrics", header
    assert header["run"] == "fixture", header
    assert header["sender"] == {"role": "learner", "index": 0}, header
    assert header["seq"] == 3 and header["policy_version"] == 42, header
    assert body["env_steps"] == 123456, body
    assert body["episodes"] == 2345, body
    assert abs(body["wall_time_s"] - 61.5) < 1e-12, body
    values = body["values"]
    assert abs(values["loss"] - 0.0125) < 1e-12, values
    assert abs(values["actor_fps"] - 812.5) < 1e-12, values
    assert values["policy_lag_max"] == 3.0, values
    print("ok: metrics readable by field name:", sorted(values))


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.stderr.write(__doc__)
        sys.exit(1)
    main(sys.argv[1])
