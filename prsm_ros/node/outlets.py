"""What the node sends out: its publishers and sinks, and a step's outputs turned into messages.

`Outlets` publishes and records the same bytes (a message is serialised once; per-step messages
come as CDR bytes from the encoder), hands a step's messages to the sinks in one batch, decimates
joint_states and internal loads, and skips per-step topics nobody reads (the node's module doc
says why that loses nothing). The internal loads have two rates: DDS's and the live views'
(`internal_loads_rate`: what a subscriber gets) and the bag's (`record_internal_loads_rate`, every
step by default). All its methods run with the node's lock held.
"""

from __future__ import annotations

import math
import time

import rclpy
from rclpy.exceptions import InvalidHandle
from rclpy.qos import DurabilityPolicy
from rclpy.serialization import serialize_message

from prsm_ros.mcap.recorder import Deferred
from prsm_ros.messages import time_ns
from prsm_ros.node.pacing import every_n_steps
from prsm_ros.node.sinks import Sinks

READER_COUNT_EVERY = 50  # steps between two counts of the per-step topics' matched readers (module doc)
WARN_THROTTLE_S = 2.0  # wall seconds between repeated warnings of one kind
PER_STEP_TOPICS = ("joint_states", "ground_truth", "wrench", "internal_loads", "command_echo", "clock")
# wall seconds a lockstep node waits, at its first command, for its per-step writers to match the readers
# there are (`Outlets.await_readers`); a bound, not a delay: a controller already matched costs nothing
FIRST_COMMAND_READER_WAIT_S = 5.0


def unmatched(handle) -> bool:
    """True when the publisher behind `handle` (rclpy's `Publisher.handle`) has no matched reader (or is destroyed,
    at shutdown: nobody to publish to either)."""
    try:
        with handle:
            return handle.get_subscription_count() == 0
    except InvalidHandle:
        return True


class WarnThrottle:
    """Log a warning of one kind at most once per WARN_THROTTLE_S wall seconds."""

    def __init__(self, logger) -> None:
        self.logger = logger
        self._warned_at: dict[str, float] = {}

    def __call__(self, key: str, text: str) -> None:
        now = time.monotonic()
        if now - self._warned_at.get(key, -math.inf) >= WARN_THROTTLE_S:
            self._warned_at[key] = now
            self.logger.warning(text)


class Outlets:
    """The node's publishers (by topic key), its sinks and the names of every topic it has."""

    def __init__(self, node, pub: dict, topic_names: dict[str, str], sinks: Sinks, unrecorded: frozenset[str],
                 warn: WarnThrottle) -> None:
        self.node, self.pub, self.topic_names, self.sinks = node, pub, topic_names, sinks
        # rclpy's bindings' publishers, taken once: `Publisher.handle` is a Python property, read per publish
        self.handles = {key: p.handle for key, p in pub.items()}
        self.unrecorded = unrecorded  # lockstep: wall-clock topics stay out of the bag (its bytes repeat)
        self.warn = warn
        self.session = node.session
        self.encoder = node.mapper.encoder()  # per-step messages straight to CDR bytes
        self.publish_failures = 0
        self.batch: list | None = None  # a step's messages for the sinks, handed over at once (`end_step`)
        # the step's internal loads for the sinks, (item, to the record, to live views), or None (`end_step`)
        self.loads: tuple | None = None
        self.unread: frozenset[str] = frozenset()  # per-step topics with no matched reader at the last count
        # every time mode (lockstep too): a publish to nobody holds the GIL for 8-16 µs, a reader count 1 µs
        self.skippable = tuple(
            k for k in PER_STEP_TOPICS if k in pub and pub[k].qos_profile.durability == DurabilityPolicy.VOLATILE)
        self.set_decimation(node.config)

    def set_decimation(self, cfg) -> None:
        self.js_every = every_n_steps(cfg.joint_states_rate, cfg.update_rate)
        # heavy outputs are decimated on DDS only in realtime and fast mode (a lockstep controller may read every
        # step); the bag at its own rate, every step unless asked
        self.il_every = 1 if cfg.time_mode == "lockstep" else every_n_steps(cfg.internal_loads_rate, cfg.update_rate)
        self.il_record_every = every_n_steps(cfg.record_internal_loads_rate, cfg.update_rate)
        self.il_recorded = self.sinks.keeps_record and "internal_loads" not in self.unrecorded
        # realtime: the bag's own messages are built by the recorder (`publish_built`), in the idle part of a period;
        # lockstep and fast have no idle part (the next command or step follows at once), and the recorder's thread
        # building them there competes for the interpreter lock (lockstep round trips: 5,917-6,154 /s against
        # 6,130-6,748)
        self.deferred = cfg.time_mode == "realtime"

    def publish(self, key: str, msg, stamp_ns: int | None = None) -> None:
        """Serialise once (per-step messages come as CDR bytes already), publish and record the same bytes."""
        if type(msg) is not bytes:
            msg = serialize_message(msg)
        if not self.no_reader(key):  # else DDS would deliver it to nobody (volatile): the sinks only
            self.send(key, msg)
        self.record(key, msg, stamp_ns)

    def publish_built(self, key: str, stamp_ns: int, encode, *args) -> None:
        """`publish(key, encode(*args), stamp_ns)`, save that a message only the bag gets is handed to it as a
        `Deferred`, built by its recorder off this thread (realtime: `deferred`)."""
        if self.deferred and not self.sinks.live_takes_messages and self.no_reader(key):
            self.record(key, Deferred(encode, *args), stamp_ns)
        else:
            self.publish(key, encode(*args), stamp_ns)

    def send(self, key: str, msg: bytes) -> None:
        """On DDS only; a sample the middleware refuses is counted and warned of, never raised."""
        handle = self.handles[key]
        try:  # rclpy's Publisher.publish minus its type dispatch: always bytes here
            with handle:
                handle.publish_raw(msg)
        except Exception as e:  # the middleware refused one sample (e.g. a stalled reliable reader): count it
            if not rclpy.ok(context=self.node.context):
                raise
            self.publish_failures += 1
            self.warn(f"publish:{key}", f"publishing on {self.topic_names[key]} failed "
                                        f"({self.publish_failures} so far): {e}")

    def no_reader(self, key: str) -> bool:
        """True when `key` had no matched reader at the last count and still has none (asked again
        now: a publish to nobody is dearer); a reader matched since gets every message from now on."""
        if key not in self.unread:
            return False
        if unmatched(self.handles[key]):
            return True
        self.unread = self.unread - {key}
        return False

    def record(self, key: str, data, stamp_ns: int | None = None) -> None:
        """To the sinks: with the step's batch when a step is being published, else at once."""
        if not self.sinks.takes_messages or key in self.unrecorded:
            return
        item = (self.topic_names[key], data, time_ns(self.session.time_s) if stamp_ns is None else stamp_ns)
        if self.batch is not None:
            self.batch.append(item)
        else:
            self.sinks.write(*item)

    def begin_step(self) -> None:
        """A step's messages go to the sinks in one hand-over: one lock and one queue append per step."""
        self.batch = [] if self.sinks.takes_messages else None

    def end_step(self) -> None:
        batch, self.batch = self.batch, None
        loads, self.loads = self.loads, None
        if loads is not None:
            self.sinks.write_step(batch or [], *loads)
        elif batch:
            self.sinks.write_many(batch)

    def await_readers(self, timeout_s: float) -> bool:
        """Wait (at most `timeout_s` wall seconds) until `joint_states` has a matched reader and every
        per-step topic has matched the readers the graph shows. True when they have.

        Discovery matches a writer and a reader on each side on its own: a controller sees our
        writers matched and sends its first command while our side may not yet have matched its
        readers. A lockstep state sent then goes to nobody (volatile) and the controller waits for
        it for ever, so the first command waits for the match instead.
        """
        end = time.monotonic() + timeout_s
        while True:
            behind = [k for k in self.skippable if self._matched(k) < self._on_graph(k)]
            if not behind and self._matched("joint_states") > 0:
                return True
            if time.monotonic() >= end:
                return False
            time.sleep(0.001)  # discovery runs on the middleware's threads; this one only polls

    def _matched(self, key: str) -> int:
        pub = self.pub.get(key)
        return 0 if pub is None or unmatched(self.handles[key]) else pub.get_subscription_count()

    def _on_graph(self, key: str) -> int:
        return self.node.count_subscribers(self.topic_names[key]) if key in self.pub else 0

    def count_readers(self) -> None:
        """Note which per-step topics have no matched reader now (`publish` skips them on DDS)."""
        self.unread = frozenset(key for key in self.skippable if unmatched(self.handles[key]))

    def publish_step(self, out, reporter, echo, force_state: bool = False) -> None:
        """A step's messages: the state first (a lockstep controller computes its next command while
        the rest goes out), events, the command echo, /clock, internal loads; its outputs to the sinks."""
        k = self.session.nstep
        ns = time_ns(out.time_s)
        enc = self.encoder
        if k % READER_COUNT_EVERY == 0:
            self.count_readers()
        if force_state or k % self.js_every == 0:
            self.publish_state(out, ns)
        reporter.step_events()
        echoed = echo.take()
        if echoed is not None:
            cmd_ns, source = echoed
            self.publish("command_echo", enc.time_reference(ns, cmd_ns, source), ns)
            echo.record_latency(cmd_ns, time.time_ns())
        if "clock" in self.pub:
            self.publish_built("clock", ns, enc.clock, ns)
        self.publish_loads(out, k, ns)
        self.sinks.submit(out)

    def publish_loads(self, out, k: int, ns: int) -> None:
        """Step `k`'s internal loads to DDS and the live views at their rate, to the bag at its own; their
        bytes (7 KB for fu2018) are built only for a step someone gets them at, and by the recorder when
        the bag alone does."""
        live = k % self.il_every == 0
        to_record = self.il_recorded and k % self.il_record_every == 0
        to_live = live and self.sinks.live_takes_messages
        to_dds = live and not self.no_reader("internal_loads")
        if not (to_dds or to_record or to_live):
            return
        if to_dds or to_live or not self.deferred:
            data = self.encoder.internal_loads(out)
            if to_dds:
                self.send("internal_loads", data)
        else:  # the bag's only: its recorder builds them, in a batch of steps off this thread (`Deferred`)
            data = Deferred(self.encoder.internal_loads, out)
        if to_record or to_live:  # either needs a message sink, so a step's batch is open (`begin_step`)
            self.loads = ((self.topic_names["internal_loads"], data, ns), to_record, to_live)

    def publish_state(self, out, ns: int) -> None:
        """joint_states and the wrench; with an actuator joint_states carries what the sensors
        measure, and the truth goes beside it on ground_truth."""
        enc, act = self.encoder, self.session.actuator
        if act is not None:
            self.publish("ground_truth", enc.joint_state(out, ns), ns)
        self.publish("joint_states", enc.joint_state(act.measured(out) if act is not None else out, ns), ns)
        self.publish_built("wrench", ns, enc.wrench, out, ns)

    def publish_rest_state(self) -> None:
        """The state just set (reset) on the state topics at once, though no step ran."""
        out = self.session.rest_outputs()
        ns = time_ns(out.time_s)
        self.publish_state(out, ns)
        if "clock" in self.pub:
            self.publish("clock", self.encoder.clock(ns), ns)
