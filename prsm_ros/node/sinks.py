"""The node's outputs besides DDS, as a list of sinks behind one protocol (`Sink`).

A sink takes a step's messages as the node publishes them (topic, CDR bytes, stamp: the MCAP
recording), or the step's outputs (the live Rerun view), or both; it reports its figures for
/diagnostics and closes within a bound. `SINKS` lists how each is opened from the configuration:
adding an output (a live server, another file format) is one entry there. Each is optional and
imported only when asked for (the recorder needs mcap, the Rerun sink rerun-sdk, the server
foxglove-sdk). A refusal (a path not writable, a bad Rerun target, a port taken) is a `ConfigError` naming the parameter; a refused start closes
the sinks already opened and leaves no empty bag behind.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any, Protocol

from prsm_sim import InternalLayout

from prsm_ros.node.parameters import ConfigError, NodeConfig, physics_parameters
from prsm_ros.node.record_path import RecordPathError, claim_record_path

DRAIN_POLL_S = 2e-5  # `Sinks.wait_drained`: the wait between two looks at a sink's backlog


class Sink(Protocol):
    """One output of the node besides DDS.

    `takes_messages`: `write`/`write_many` get every published and received message as
    (topic name, CDR bytes or message, stamp ns), and a sink that `keeps_record` also a realtime
    node's internal loads as a `prsm_ros.mcap.recorder.Deferred` at steps nobody else gets them;
    `takes_outputs`: `submit` gets each step's `Outputs`. Every call is O(1) on the step thread (queue and return); a sink never raises into
    the node, it sets `error` and counts what it lost.
    """

    takes_messages: bool
    takes_outputs: bool
    # the run's record (the bag): the internal loads at the record's rate; otherwise a live view, which gets
    # them at their DDS rate, as a subscriber would
    keeps_record: bool
    error: str | None

    def write(self, topic: str, data: Any, stamp_ns: int) -> None: ...

    def write_many(self, items: list[tuple[str, Any, int]]) -> None: ...

    def submit(self, out: Any) -> None: ...

    def backlogged(self) -> bool:
        """True while the sink holds more than half of what it can queue (fast mode waits for it)."""
        ...

    def report(self) -> dict[str, Any]:
        """Its figures for /diagnostics, keys prefixed with its name."""
        ...

    def close(self, timeout_s: float) -> bool:
        """Flush and close within `timeout_s`; True when everything went out (idempotent)."""
        ...


class RecorderSink:
    """The MCAP recording (`McapProcessRecorder`; `McapRecorder` in fast mode: `open_recorder`) as a sink of
    messages."""

    takes_messages, takes_outputs, keeps_record = True, False, True

    def __init__(self, recorder) -> None:
        self.recorder = recorder
        self.write = recorder.write
        self.write_many = recorder.write_many

    @property
    def error(self) -> str | None:
        return self.recorder.error

    def submit(self, out: Any) -> None:
        return None

    def backlogged(self) -> bool:
        return self.recorder.backlog() > self.recorder.queue_size // 2

    def report(self) -> dict[str, Any]:
        r = self.recorder
        return {"record_path": str(r.path), "record_written": r.messages_written,
                "record_dropped": r.messages_dropped, "record_error": r.error or ""}

    def close(self, timeout_s: float) -> bool:
        return self.recorder.close(timeout_s=timeout_s)

    def describe_failure(self) -> str:
        return f"{self.recorder.error} ({self.recorder.messages_dropped} messages not recorded)"


class LiveViewSink:
    """A live view (Rerun, Foxglove) as a sink: it drops and counts rather than slowing the simulation,
    reports its own figures under `prefix`, and takes nothing it is not given a method for."""

    takes_messages, takes_outputs, keeps_record = False, False, False

    def __init__(self, view, prefix: str) -> None:
        self.view, self.prefix = view, prefix

    @property
    def error(self) -> str | None:
        return self.view.error

    def write(self, topic: str, data: Any, stamp_ns: int) -> None:
        return None

    def write_many(self, items: list[tuple[str, Any, int]]) -> None:
        return None

    def submit(self, out: Any) -> None:
        return None

    def backlogged(self) -> bool:
        return False

    def report(self) -> dict[str, Any]:
        return {f"{self.prefix}_{k}": v for k, v in self.view.stats().items() if v is not None}

    def close(self, timeout_s: float) -> bool:
        return self.view.close(timeout_s=timeout_s)

    def describe_failure(self) -> str:
        return str(self.view.error)


class RerunOutputSink(LiveViewSink):
    """The live Rerun view (`prsm_ros.viz.sink.RerunSink`) as a sink of step outputs."""

    takes_outputs = True

    def __init__(self, rerun) -> None:
        super().__init__(rerun, "rerun")
        self.rerun = rerun
        self.submit = rerun.submit


class Sinks:
    """The node's sinks in order: messages to those that take messages, outputs to those that take outputs."""

    def __init__(self, sinks: list) -> None:
        self.all = list(sinks)
        self.message_sinks = [s for s in self.all if s.takes_messages]
        self.output_sinks = [s for s in self.all if s.takes_outputs]
        self.takes_messages = bool(self.message_sinks)
        self.keeps_record = any(s.keeps_record for s in self.message_sinks)
        self.live_takes_messages = any(not s.keeps_record for s in self.message_sinks)

    def __iter__(self):
        return iter(self.all)

    def of(self, kind: type):
        """The first sink of class `kind`, or None."""
        return next((s for s in self.all if isinstance(s, kind)), None)

    def write(self, topic: str, data: Any, stamp_ns: int) -> None:
        for s in self.message_sinks:
            s.write(topic, data, stamp_ns)

    def write_many(self, items: list[tuple[str, Any, int]]) -> None:
        for s in self.message_sinks:
            s.write_many(items)

    def write_step(self, items: list[tuple[str, Any, int]], loads: tuple[str, Any, int], to_record: bool,
                   to_live: bool) -> None:
        """A step's messages, then its internal loads (`loads`) to the record when `to_record` and to the
        live views when `to_live` (their two rates: `Outlets.publish_loads`)."""
        items.append(loads)
        for s in self.message_sinks:
            if to_record if s.keeps_record else to_live:
                s.write_many(items)
            elif len(items) > 1:
                s.write_many(items[:-1])

    def submit(self, out: Any) -> None:
        for s in self.output_sinks:
            s.submit(out)

    def wait_drained(self, stop) -> None:
        """Until no sink is backlogged (or one failed, or `stop` is set): fast mode keeps every message."""
        for s in self.all:
            while s.backlogged() and s.error is None and not stop.is_set():
                time.sleep(DRAIN_POLL_S)

    def report(self) -> tuple[dict[str, Any], list[str]]:
        values: dict[str, Any] = {}
        problems = []
        for s in self.all:
            values.update(s.report())
            if s.error:
                problems.append(str(s.error))
        return values, problems

    def close(self, timeout_s: float, log_error: Callable[[str], None]) -> None:
        """Close each in order, each within `timeout_s`; a failure is logged, never raised."""
        for s in self.all:
            if not s.close(timeout_s):
                log_error(s.describe_failure())


def open_recorder(cfg: NodeConfig, node_name: str, channels: dict, layout: InternalLayout):
    """The MCAP recorder at `record_path` (a directory or a {node} pattern claims a fresh file), or None."""
    if not cfg.record:
        return None
    from prsm_ros.mcap.recorder import McapRecorder, run_metadata
    from prsm_ros.mcap.recorder_process import McapProcessRecorder
    node_params = {**cfg.values, **physics_parameters(cfg.params)}
    meta = run_metadata(cfg.params, preset=cfg.preset, model=cfg.model, dt_s=cfg.dt_s, node_parameters=node_params)
    try:
        path = claim_record_path(cfg.record_path, node_name)
    except RecordPathError as e:
        raise ConfigError(f"parameter record_path = {cfg.record_path!r}: {e}") from None
    # realtime and lockstep: a controller waits on every step, so the writer runs in a process of its own, whose
    # Python never holds the lock the step thread needs (period jitter p99 over its floor, median of alternated
    # runs: 3.5x with the thread, 1.7x with the process). fast: the node waits on the writer's backlog instead, and
    # the thread moves about twice the messages per second (no second packing and pipe)
    Recorder = McapRecorder if cfg.time_mode == "fast" else McapProcessRecorder
    rec = Recorder(path, metadata=meta, deterministic=cfg.time_mode == "lockstep")  # lockstep: golden bytes
    if rec.error:
        rec.close()
        raise ConfigError(f"parameter record_path = {cfg.record_path!r}: {rec.error}")
    for name, (msg_class, qos, untrusted) in channels.items():  # untrusted: bytes from other participants
        rec.add_channel(name, msg_class, qos, untrusted=untrusted)
    return RecorderSink(rec)


def _discard_recording(sink: RecorderSink) -> None:
    """A refused start: no run happened, so no (empty) bag is left behind."""
    sink.recorder.close()
    sink.recorder.path.unlink(missing_ok=True)


def open_rerun(cfg: NodeConfig, node_name: str, channels: dict, layout: InternalLayout):
    """The live Rerun sink, or None (parameter rerun off, or the RERUN environment variable turns it off)."""
    from prsm_ros.viz.sink import RerunSink, rerun_forced_off
    if cfg.rerun == "off" or rerun_forced_off():
        return None
    try:
        return RerunOutputSink(RerunSink(cfg.rerun, cfg.rerun_target, cfg.params, layout, cfg.model))
    except (ValueError, RuntimeError) as e:
        raise ConfigError(str(e)) from None


class FoxgloveSink(LiveViewSink):
    """The live Foxglove server (`prsm_ros.live.foxglove_server.FoxgloveLive`) as a sink of messages:
    the viewers get what the bag gets, as it happens."""

    takes_messages = True

    def __init__(self, live) -> None:
        super().__init__(live, "foxglove")
        self.live = live
        self.write = live.write
        self.write_many = live.write_many


def open_foxglove(cfg: NodeConfig, node_name: str, channels: dict, layout: InternalLayout):
    """The live Foxglove server on `foxglove_host`:`foxglove_port` serving `channels`, or None (port 0)."""
    if cfg.foxglove_port == 0:
        return None
    from prsm_ros.live.foxglove_server import FoxgloveLive, LiveError
    try:
        live = FoxgloveLive(cfg.foxglove_host, cfg.foxglove_port, name=node_name)
    except LiveError as e:
        raise ConfigError(f"parameters foxglove_host = {cfg.foxglove_host!r}, foxglove_port = {cfg.foxglove_port}: "
                          f"{e}") from None
    try:
        live.add_ros_channels(channels)
    except BaseException:
        live.close()
        raise
    return FoxgloveSink(live)


# How each sink is opened: (cfg, node's full name, channels, layout) → a Sink or None (not asked for).
# `channels` maps each recorded topic name to (message class, QoS profile, whether other participants write it).
SINKS: list[Callable[..., Any]] = [open_recorder, open_rerun, open_foxglove]


def open_sinks(cfg: NodeConfig, node_name: str, channels: dict, layout: InternalLayout) -> Sinks:
    """Every sink of `SINKS` that `cfg` asks for, in order; on a refusal those already open are closed."""
    opened: list = []
    try:
        for opener in SINKS:
            sink = opener(cfg, node_name, channels, layout)
            if sink is not None:
                opened.append(sink)
    except BaseException:
        for sink in opened:
            _discard_recording(sink) if isinstance(sink, RecorderSink) else sink.close(1.0)
        raise
    return Sinks(opened)
