"""Serve ROS 2 messages live to Foxglove over its WebSocket protocol (foxglove-sdk), without a ROS bridge.

    live = FoxgloveLive("127.0.0.1", 8765, name="/prsm_actuator")
    live.add_channel(ros_channel("/joint_states", JointState, qos))
    live.write("/joint_states", cdr_bytes, stamp_ns)   # per message, from the step thread
    live.close()

Each channel is named by its resolved ROS topic and carries what a ROS 2 MCAP bag carries
(`prsm_ros.mcap.schema`): schema `pkg/msg/Type` in `ros2msg` encoding with its dependent
definitions, message encoding `cdr`, the bytes the node publishes, and the `offered_qos_profiles`
and `topic_type_hash` metadata. So Foxglove decodes the live stream exactly as it decodes the
bag, and the layout `prsm-bag layout` writes for a bag of the same node fits the live connection.

The SDK's server runs on its own threads; `write` hands the bytes to it and returns. Each client
has a bounded queue (`BACKLOG` messages): a client that reads too slowly loses the oldest
messages, never the step thread's time. With no client subscribed, a write costs a lookup.

Latched topics (transient local: `robot_description`, `~/internal_loads/labels`) are published
once at start-up, usually before any viewer connects; as DDS does for a late reader, the server
keeps the last message of each and sends it again whenever a client subscribes to it.

The server binds to `host` (the node's default: 127.0.0.1, this machine only): anyone who can
reach the port can read every topic, with no authentication (docs/security.md).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

from prsm_sim.errors import PrsmError

from prsm_ros.mcap import schema as mcap_schema

DEFAULT_HOST = "127.0.0.1"
BACKLOG = 4096  # messages queued per client: a few steps' worth of every topic at 1 kHz


class LiveError(PrsmError, RuntimeError):
    """The live server could not start (port taken, host unknown, SDK missing); the message says which."""


@dataclass(frozen=True)
class ChannelSpec:
    """One served channel, as a ROS 2 MCAP bag declares it."""

    topic: str  # the resolved ROS topic, e.g. /joint_states
    schema_name: str  # pkg/msg/Type
    schema_data: bytes  # ros2msg text with every dependent definition
    metadata: dict[str, str] = field(default_factory=dict)
    message_encoding: str = mcap_schema.MESSAGE_ENCODING
    schema_encoding: str = mcap_schema.SCHEMA_ENCODING

    @property
    def latched(self) -> bool:
        """Transient local as the QoS metadata declares it (durability 1 in `offered_qos_profiles`)."""
        return "durability: 1\n" in self.metadata.get("offered_qos_profiles", "")


def ros_channel(topic: str, msg_class, qos) -> ChannelSpec:
    """The channel of `topic` carrying the rclpy `msg_class`, with the QoS the node offers or requests."""
    name = mcap_schema.type_name(msg_class)
    meta = {"offered_qos_profiles": mcap_schema.offered_qos_profiles_yaml(qos)}
    type_hash = mcap_schema.type_hash(name)
    if type_hash:
        meta["topic_type_hash"] = type_hash
    return ChannelSpec(topic=topic, schema_name=name, schema_data=mcap_schema.full_definition(name).encode("utf-8"),
                       metadata=meta)


def _listener(live: FoxgloveLive):
    """A `foxglove.websocket.ServerListener` telling `live` of each subscription (its base class
    comes from the SDK, imported only when a server starts)."""
    from foxglove.websocket import ServerListener

    class Listener(ServerListener):
        def on_subscribe(self, client, channel) -> None:
            live._subscribed(channel.topic)

    return Listener()


class FoxgloveLive:
    """A Foxglove WebSocket server on `host:port` with its own SDK context (nothing global).

    `port` 0 takes a free port (`self.port` says which). `time`: advertise the Time capability,
    so `broadcast_time` sets the viewer's clock (a bag played back). `subscribed` is set at the
    first subscription of any client. Raises LiveError when the server cannot start.
    """

    def __init__(self, host: str, port: int, *, name: str = "prsm", time: bool = False) -> None:
        try:
            import foxglove
        except ImportError as e:
            raise LiveError(f"the live Foxglove view needs the Foxglove SDK (pip install 'prsm[foxglove]'): "
                            f"{e}") from None
        self._foxglove = foxglove
        # set before the server starts: its threads may call `_subscribed` at once
        self.host = host
        self.error: str | None = None
        self.messages_written = 0
        self.subscribed = threading.Event()
        self._channels: dict[str, object] = {}
        self._latched: dict[str, tuple[bytes, int] | None] = {}  # latched topic → its last message
        self._closed = False
        self._context = foxglove.Context()
        caps = [foxglove.Capability.Time] if time else []
        try:
            self._server = foxglove.start_server(name=name, host=host, port=port, context=self._context,
                                                 capabilities=caps, message_backlog_size=BACKLOG,
                                                 server_listener=_listener(self))
        except RuntimeError as e:  # the SDK's FoxgloveError: bind failures, bad addresses
            raise LiveError(f"cannot serve Foxglove on {host}:{port}: {e}") from None
        self.port = int(self._server.port)

    @property
    def url(self) -> str:
        """What to type into Foxglove's "Open connection → Foxglove WebSocket"."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}"

    def add_channel(self, spec: ChannelSpec) -> None:
        """Advertise `spec` to every client (now and later). Re-adding a topic is a no-op."""
        if spec.topic in self._channels:
            return
        fg = self._foxglove
        schema = fg.Schema(name=spec.schema_name, encoding=spec.schema_encoding, data=spec.schema_data)
        if spec.latched:
            self._latched[spec.topic] = None
        self._channels[spec.topic] = fg.Channel(spec.topic, schema=schema, message_encoding=spec.message_encoding,
                                                context=self._context, metadata=dict(spec.metadata))

    def add_ros_channels(self, channels: dict) -> None:
        """The node's channels: topic → (message class, QoS profile, untrusted), as the recorder takes them."""
        for topic, (msg_class, qos, _untrusted) in channels.items():
            self.add_channel(ros_channel(topic, msg_class, qos))

    def write(self, topic: str, data, stamp_ns: int) -> None:
        """Send `data` on `topic` to its subscribed clients, stamped `stamp_ns`; never blocks.

        `data`: CDR bytes, or an rclpy message (the node's few inputs it takes as messages),
        serialized here as the recorder does.
        """
        if self._closed:
            return
        channel = self._channels.get(topic)
        if channel is None:
            raise KeyError(f"topic {topic!r} was not added with add_channel; "
                           f"added: {', '.join(self._channels) or 'none'}")
        if type(data) is not bytes:
            from rclpy.serialization import serialize_message
            data = serialize_message(data)
        if topic in self._latched:
            self._latched[topic] = (data, stamp_ns)
        try:
            channel.log(data, log_time=stamp_ns)
        except Exception as e:  # the SDK's own error types: the view stops, the run goes on
            self.error = self.error or f"Foxglove live view on {self.url} failed: {type(e).__name__}: {e}"
            return
        self.messages_written += 1

    def write_many(self, items) -> None:
        """Several `(topic, data, stamp_ns)` in order."""
        for topic, data, stamp_ns in items:
            self.write(topic, data, stamp_ns)

    def _subscribed(self, topic: str) -> None:
        """A client subscribed to `topic` (the server's thread): a latched topic's last message again."""
        self.subscribed.set()
        last = self._latched.get(topic)
        if last is not None and not self._closed:
            try:
                self._channels[topic].log(last[0], log_time=last[1])
            except Exception as e:  # the SDK's own error types: noted, the run goes on
                self.error = self.error or f"Foxglove live view on {self.url} failed: {type(e).__name__}: {e}"

    def broadcast_time(self, stamp_ns: int) -> None:
        """Set the clients' current time (needs `time=True`)."""
        if not self._closed:
            self._server.broadcast_time(int(stamp_ns))

    def stats(self) -> dict[str, object]:
        """For /diagnostics."""
        return {"url": self.url, "written": self.messages_written, "error": self.error or ""}

    def close(self, timeout_s: float | None = None) -> bool:
        """Stop the server (idempotent); True when it ran without error. `timeout_s`: unused, the
        SDK stops at once (the argument matches the other sinks' close)."""
        if not self._closed:
            self._closed = True
            for channel in self._channels.values():
                channel.close()
            self._server.stop()
        return self.error is None

    def __enter__(self) -> FoxgloveLive:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
