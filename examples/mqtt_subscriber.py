"""Follow a cell's MQTT topics and print its results: an example historian client (docs/mqtt.md).

    python examples/mqtt_subscriber.py --host 127.0.0.1 --port 1883 \
        --prefix acme-rail/plant-2/body-shop/line-4/glazing-1/cellctl

It keeps a persistent session (a fixed client id, clean_session false) and subscribes with QoS 1,
so the broker keeps the results published while it is away; it drops duplicates by ``msg_id``
and reconnects with back-off. ``--count N`` exits after N results (0: run until Ctrl-C).
Needs only aiomqtt (``pip install aiomqtt``).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import random
import sys
from typing import Any

import aiomqtt


def describe(topic: str, prefix: str, body: dict[str, Any] | None) -> str:
    """One line for a message."""
    name = topic.removeprefix(prefix + "/")
    if body is None:
        return f"{name}: (cleared)"
    if name == "result":
        dev = body.get("measured_deviation") or {}
        figures = " ".join(f"{k}={v:+.3f}" for k, v in dev.items())
        verdict = "OK " if body.get("ok") else f"NOK {body.get('error_code')}"
        return f"result cycle {body.get('cycle_id')} part {body.get('part_id')}: {verdict} {figures} ({body.get('cycle_time_s', 0):.1f} s)"
    if name == "status":
        return f"status: {'online' if body.get('online') else 'offline'} ({body.get('reason')})"
    if name == "state":
        return f"state: {body.get('state')} / {body.get('mode')} / {body.get('cycle_step')}"
    if name == "alarm/events":
        return f"alarm {body.get('code')} {body.get('event')}: {body.get('message')}"
    return f"{name}: {json.dumps(body, sort_keys=True)}"


async def follow(args: argparse.Namespace) -> int:
    seen: set[str] = set()
    results = 0
    delay = 0.5
    while True:
        try:
            async with aiomqtt.Client(args.host, args.port, identifier=args.client_id, clean_session=False,
                                      keepalive=10, timeout=10) as client:  # fmt: skip
                delay = 0.5
                await client.subscribe(f"{args.prefix}/#", qos=1, timeout=10)
                print(f"subscribed to {args.prefix}/# on {args.host}:{args.port}", flush=True)
                async for msg in client.messages:
                    raw = bytes(msg.payload) if isinstance(msg.payload, (bytes, bytearray)) else str(msg.payload or "").encode()
                    body = json.loads(raw) if raw else None
                    if body is not None and body.get("msg_id") in seen:
                        continue  # at least once: a duplicate
                    if body is not None:
                        seen.add(body["msg_id"])
                    print(describe(str(msg.topic), args.prefix, body), flush=True)
                    if str(msg.topic) == f"{args.prefix}/result":
                        results += 1
                        if args.count and results >= args.count:
                            return 0
        except aiomqtt.MqttError as err:
            print(f"broker {args.host}:{args.port}: {err}; again in {delay:.1f} s", file=sys.stderr, flush=True)
            await asyncio.sleep(random.uniform(delay / 2, delay))
            delay = min(delay * 2, 15.0)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=1883)
    p.add_argument("--prefix", required=True, help="the cell's topic prefix, e.g. acme/site/area/line/cell/cellctl")
    p.add_argument("--client-id", default="cellctl-example-historian", help="fixed: the broker keeps this session")
    p.add_argument("--count", type=int, default=0, help="exit after this many results (0: never)")
    p.add_argument("--timeout", type=float, default=0.0, help="give up after this many seconds (0: never)")
    args = p.parse_args(argv)
    try:
        return asyncio.run(asyncio.wait_for(follow(args), args.timeout or None))
    except TimeoutError:
        print("timed out", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
