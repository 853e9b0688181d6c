#!/usr/bin/env python3
"""Ask a running `fsrl serve` for an action through its queryable (no ROS needed).

    fsrl serve models/fsrl-env1-visible-s0.fsrlm --listen tcp/127.0.0.1:7450 &
    python3 tools/serve_client.py --connect tcp/127.0.0.1:7450

Request and reply are MessagePack maps with named fields (proto/src/serve.rs): world frame,
metres, seconds, radians. A person's radius_m, goal_x_m/goal_y_m, v_pref_mps and standing are
optional.
"""
import argparse
import json

import msgpack
import zenoh


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--connect", default="tcp/127.0.0.1:7450")
    ap.add_argument("--name", default="fsrl")
    args = ap.parse_args()
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("connect/endpoints", json.dumps([args.connect]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    request = {
        "robot": {"x_m": 0.0, "y_m": -4.0, "vx_mps": 0.0, "vy_mps": 0.0, "heading_rad": 1.5708},
        "goal": {"x_m": 0.0, "y_m": 4.0},
        "humans": [
            {"x_m": 1.0, "y_m": 0.0, "vx_mps": -0.5, "vy_mps": 0.0},
            {"x_m": -2.0, "y_m": 1.0, "vx_mps": 0.3, "vy_mps": -0.2, "radius_m": 0.35},
        ],
        "steps": 0,
    }
    with zenoh.open(conf) as session:
        for reply in session.get(f"fsrl/serve/{args.name}/act", payload=msgpack.packb(request), timeout=5.0):
            if reply.ok is None:
                continue
            answer = msgpack.unpackb(reply.ok.payload.to_bytes())
            print(json.dumps(answer, indent=2))
            return 0 if answer["ok"] else 1
    print("no reply: is fsrl serve running and reachable?")
    return 1


if __name__ == "__main__":
    raise SystemExit(main())
