#!/usr/bin/env python3
"""Watch an fsrl run's live metrics from Python (PyPI: eclipse-zenoh, msgpack).

    python3 tools/watch_metrics.py --connect tcp/127.0.0.1:7447 --run local [--count N] [--timeout S]
    python3 tools/watch_metrics.py --connect tls/10.0.0.1:7447 --run cluster \
        --root-ca /etc/fsrl/certs/ca.crt --user monitor --password-file /etc/fsrl/monitor.password
(the second: a client of a cluster's router over TLS with credentials, see deploy/README.md)

Subscribes to fsrl/<run>/metrics/** and prints one line per message:
<role>-<index> episodes=<n> env_steps=<n> <name>=<value> ...
Every message is MessagePack with field names: msg["header"]["sender"], msg["body"]["values"].
Exits 0 after --count messages (0: run until --timeout / Ctrl-C); 3 if --count was not reached.
"""
import argparse
import json
import sys
import time

try:
    import msgpack
    import zenoh
except ImportError as e:
    sys.stderr.write(f"missing python module ({e}): pip install eclipse-zenoh msgpack\n")
    sys.exit(2)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--connect", action="append", required=True, help="zenoh endpoint, e.g. tcp/127.0.0.1:7447")
    ap.add_argument("--run", default="local", help="run id")
    ap.add_argument("--count", type=int, default=0, help="exit after this many messages")
    ap.add_argument("--timeout", type=float, default=0.0, help="give up after this many seconds")
    ap.add_argument("--root-ca", help="CA certificate (PEM) for tls/ endpoints")
    ap.add_argument("--user", help="user name for the router's user/password authentication")
    ap.add_argument("--password-file", help="file whose first line is the password (with --user)")
    args = ap.parse_args()

    conf = zenoh.Config()
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/endpoints", json.dumps(args.connect))
    if args.user or args.root_ca:
        # A client of a cluster's router (deploy/router.json5).
        conf.insert_json5("mode", '"client"')
        if args.root_ca:
            conf.insert_json5("transport/link/tls/root_ca_certificate", json.dumps(args.root_ca))
        if args.user:
            if not args.password_file:
                ap.error("--user needs --password-file")
            with open(args.password_file) as f:
                password = f.readline().rstrip("\r\n")
            conf.insert_json5("transport/auth/usrpwd/user", json.dumps(args.user))
            conf.insert_json5("transport/auth/usrpwd/password", json.dumps(password))
    else:
        conf.insert_json5("mode", '"peer"')
        conf.insert_json5("listen/endpoints", json.dumps(["tcp/127.0.0.1:0"]))
    key = f"fsrl/{args.run}/metrics/**"
    seen = 0
    deadline = time.monotonic() + args.timeout if args.timeout > 0 else None
    with zenoh.open(conf) as session:
        sub = session.declare_subscriber(key)
        while True:
            if deadline is not None and time.monotonic() > deadline:
                break
            sample = sub.try_recv()
            if sample is None:
                time.sleep(0.05)
                continue
            msg = msgpack.unpackb(sample.payload.to_bytes(), raw=False)
            header, body = msg["header"], msg["body"]
            sender = f'{header["sender"]["role"]}-{header["sender"]["index"]}'
            values = " ".join(f"{k}={v:.4g}" for k, v in sorted(body["values"].items()))
            print(f'{sender} episodes={body["episodes"]} env_steps={body["env_steps"]} {values}', flush=True)
            seen += 1
            if args.count and seen >= args.count:
                return 0
    return 3 if args.count else 0


if __name__ == "__main__":
    sys.exit(main())
