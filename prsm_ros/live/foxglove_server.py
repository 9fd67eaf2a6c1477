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

The server binds to `host` (the node's default: 127.0.0.1, this machine only): anyone who can
reach the port can read every topic, with no authentication (docs/security.md).
"""

from __future__ import annotations

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


def ros_channel(topic: str, msg_class, qos) -> ChannelSpec:
    """The channel of `topic` carrying the rclpy `msg_class`, with the QoS the node offers or requests."""
    name = mcap_schema.type_name(msg_class)
    meta = {"offered_qos_profiles": mcap_schema.offered_qos_profiles_yaml(qos)}
    type_hash = mcap_schema.type_hash(name)
    if type_hash:
        meta["topic_type_hash"] = type_hash
    return ChannelSpec(topic=topic, schema_name=name, schema_data=mcap_schema.full_definition(name).encode("utf-8"),
                       metadata=meta)


class FoxgloveLive:
    """A Foxglove WebSocket server on `host:port` with its own SDK context (nothing global).

    `port` 0 takes a free port (`self.port` says which). `time`: advertise the Time capability,
    so `broadcast_time` sets the viewer's clock (a bag played back). `listener`: a
    `foxglove.websocket.ServerListener` (e.g. told of subscriptions). Raises LiveError when the
    server cannot start.
    """

    def __init__(self, host: str, port: int, *, name: str = "prsm", time: bool = False, listener=None) -> None:
        try:
            import foxglove
        except ImportError as e:
            raise LiveError(f"the live Foxglove view needs the Foxglove SDK (pip install 'prsm[foxglove]'): {e}") from None
        self._foxglove = foxglove
        self._context = foxglove.Context()
        caps = [foxglove.Capability.Time] if time else []
        try:
            self._server = foxglove.start_server(name=name, host=host, port=port, context=self._context,
                                                 capabilities=caps, message_backlog_size=BACKLOG,
                                                 server_listener=listener)
        except RuntimeError as e:  # the SDK's FoxgloveError: bind failures, bad addresses
            raise LiveError(f"cannot serve Foxglove on {host}:{port}: {e}") from None
        self.host = host
        self.port = int(self._server.port)
        self.error: str | None = None
        self.messages_written = 0
        self._channels: dict[str, object] = {}
        self._closed = False

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
        self._channels[spec.topic] = fg.Channel(spec.topic, schema=schema, message_encoding=spec.message_encoding,
                                                context=self._context, metadata=dict(spec.metadata))

    def add_ros_channels(self, channels: dict) -> None:
        """The node's channels: topic → (message class, QoS profile, untrusted), as the recorder takes them."""
        for topic, (msg_class, qos, _untrusted) in channels.items():
            self.add_channel(ros_channel(topic, msg_class, qos))

    def write(self, topic: str, data: bytes, stamp_ns: int) -> None:
        """Send `data` (CDR bytes) on `topic` to its subscribed clients, stamped `stamp_ns`; never blocks."""
        if self._closed:
            return
        channel = self._channels.get(topic)
        if channel is None:
            raise KeyError(f"topic {topic!r} was not added with add_channel; added: {', '.join(self._channels) or 'none'}")
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
