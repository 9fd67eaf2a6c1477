"""`prsm-bag serve BAG`: a recorded bag served to Foxglove over its WebSocket protocol, as the node serves a run.

Every channel of the bag is advertised at once with the schema, encoding and metadata the bag
holds, so the layout `prsm-bag layout BAG` writes fits the connection as it fits the file. Once
the first client subscribes to a channel (`--no-wait`: at once), the messages go out as recorded
(the CDR bytes, no decoding), paced in real time × `--rate` on absolute deadlines from the bag's
log times, and the server's clock follows the bag time (Foxglove's Time capability). `--loop`
starts again from the first message until Ctrl-C (exit 130).
"""

from __future__ import annotations

import sys
import time

from prsm_ros.bag.reader import Bag, BagError, open_bag
from prsm_ros.live.foxglove_server import DEFAULT_HOST, ChannelSpec, FoxgloveLive, LiveError

DEFAULT_PORT = 8765  # Foxglove's own default for a WebSocket connection
TIME_EVERY_NS = 10_000_000  # the viewer's clock is set at most every 10 ms of bag time


def bag_channels(bag: Bag) -> list[ChannelSpec]:
    """Every channel the bag declares (as far as it was read: an unfinished bag's are found as it is read)."""
    out = []
    for channel in bag._channels.values():
        schema = bag._schemas.get(channel.schema_id)
        out.append(_spec(schema, channel))
    return out


def _spec(schema, channel) -> ChannelSpec:
    return ChannelSpec(topic=channel.topic, schema_name=schema.name if schema else "",
                       schema_data=bytes(schema.data) if schema else b"", metadata=dict(channel.metadata),
                       message_encoding=channel.message_encoding, schema_encoding=schema.encoding if schema else "")


def play_once(bag: Bag, live: FoxgloveLive, rate: float) -> int:
    """Send every message of `bag` once, paced at `rate` × real time; returns how many were sent."""
    start_wall = time.monotonic()
    first = None
    last_time = -TIME_EVERY_NS
    n = 0
    for schema, channel, message in bag.raw_messages():
        t = message.log_time
        first = t if first is None else first
        delay = start_wall + (t - first) * 1e-9 / rate - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        live.add_channel(_spec(schema, channel))  # a no-op unless an unfinished bag showed it only now
        if t - last_time >= TIME_EVERY_NS:
            live.broadcast_time(t)
            last_time = t
        live.write(channel.topic, bytes(message.data), t)
        n += 1
    return n


def serve(bag: Bag, host: str, port: int, *, rate: float = 1.0, loop: bool = False, wait: bool = True,
          out=sys.stdout) -> int:
    """Serve `bag` until it has been played (each pass once, or until Ctrl-C with `loop`); returns the messages sent."""
    with FoxgloveLive(host, port, name=f"prsm-bag serve {bag.path.name}", time=True) as live:
        for spec in bag_channels(bag):
            live.add_channel(spec)
        print(f"serving {bag.path} on {live.url} (Foxglove: Open connection → Foxglove WebSocket)", file=out,
              flush=True)
        if wait:
            print("waiting for a client to subscribe (Ctrl-C to stop)", file=out, flush=True)
            while not live.subscribed.wait(0.2):
                pass
        total = passes = 0
        while True:
            t0 = time.monotonic()
            sent = play_once(bag, live, rate)
            total += sent
            passes += 1
            print(f"pass {passes}: {sent} messages in {time.monotonic() - t0:.2f} s", file=out, flush=True)
            if not loop or sent == 0:
                return total


def _cmd_serve(args) -> int:
    if not args.rate > 0:
        raise BagError(f"--rate {args.rate}: must be a number > 0 (1 = real time)")
    if not 0 <= args.port <= 65535:
        raise BagError(f"--port {args.port}: must be 0..65535 (0: any free port)")
    bag = open_bag(args.bag)
    try:
        serve(bag, args.host, args.port, rate=args.rate, loop=args.loop, wait=not args.no_wait)
    except LiveError as e:
        raise BagError(str(e)) from None
    return 0


def add_parser(sub) -> None:
    """`serve` on the `prsm-bag` subcommands."""
    p = sub.add_parser("serve", help="serve to Foxglove over its WebSocket protocol, as the node serves a live run")
    p.add_argument("bag")
    p.add_argument("--port", type=int, default=DEFAULT_PORT,
                   help=f"TCP port (default {DEFAULT_PORT}; 0: any free port)")
    p.add_argument("--host", default=DEFAULT_HOST,
                   help=f"address to bind (default {DEFAULT_HOST}: this machine only; 0.0.0.0 exposes the bag to "
                        "the network, unauthenticated)")
    p.add_argument("--rate", type=float, default=1.0, help="playback speed factor (default 1 = real time)")
    p.add_argument("--loop", action="store_true", help="start again at the end, until Ctrl-C")
    p.add_argument("--no-wait", action="store_true", help="start at once instead of at the first subscription")
    p.set_defaults(func=_cmd_serve)
