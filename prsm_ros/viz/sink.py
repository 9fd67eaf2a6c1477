"""Rerun output of a running simulation: `RerunSink` for the node, `RecordingWriter` shared with the bag converter.

    sink = RerunSink("save", "run.rrd", params, sim.layout, "jones2016")   # or spawn / connect / off
    sink.submit(out)        # per step, from the 1 kHz loop: appends to a bounded queue, nothing else
    sink.close()            # drains the queue, finalises the file

A background thread sends what the loop queued at two periods, every step's scalar outputs kept:

- every `flush_period_s` (0.2 s): the scalar outputs' series (position, force, speed, torque,
  powers, …), so the plots lag the loop by at most that;
- every `loads_period_s` (1 s): the internal loads' series (per roller) for the first step of each
  1/loads_rate_hz (120 Hz) of simulation time, and the 3D scene (poses, arrows, tooth points, heat
  maps) for the first step of each 1/scene_rate_hz (30 Hz), a step the loads' series also holds.

Every step's scalar outputs are sent; the internal loads are sampled because reading a step's
internal vector is the costliest part of a row (fu2018: its ~830 labelled loads expanded per step,
10-70 µs on the 2-core VM, against 6-15 µs for the scalar outputs), and plots refreshed a few times a
second show no more at 1 kHz than at 120 Hz. `loads_rate_hz=None` keeps every step's loads; a bag
keeps every step and `bag_to_rrd` converts every step.

Rerun's cost is per entity and send, hardly per row (about 0.1 ms of the SDK's own work per entity
and send on the 2-core VM, beside the Python that builds the columns), and a batch holds about 20
scalar entities and, for fu2018, 50 for the loads and scene; the periods set the cost:
`prsm-bench --only rerun` measures it beside a 1 kHz loop (docs/performance.md). Each send gathers
its entities into few Arrow record batches (`columns.BatchedStream`). It logs
through an explicit `RecordingStream`, never the global one. The loop is never blocked: a full
queue drops the step and counts it in `dropped`; a Rerun failure sets `error` and the loop runs on.

Modes and targets (the node's `rerun` and `rerun_target` parameters):

- `off`: nothing is imported or started. The environment variable RERUN=off (also 0/false/no) forces it.
- `save`: write an .rrd to `target` ("" → ./prsm_<UTC yyyymmdd_HHMMSS>.rrd), blueprint included.
- `spawn`: start a native viewer and stream to it; `target` is its port ("" → 9876).
- `connect`: stream to a running viewer or `rerun --serve-grpc`; `target` is a URL
  `rerun+http://host:port/proxy`, `host:port` or a port ("" → rerun+http://127.0.0.1:9876/proxy).

This module imports `rerun` only when a sink or writer is actually made, so importing it costs nothing.
"""

from __future__ import annotations

import atexit
import math
import os
import struct
import threading
import time
import uuid
from collections import deque
from collections.abc import Iterable, Mapping
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from prsm_sim import OUTPUT_FIELDS, InternalLayout, Outputs, ParamError, Params, PrsmError, State
from prsm_sim.stepping.trajectory import trajectory_from_rows

MODES = ("off", "save", "spawn", "connect")
APPLICATION_ID = "prsm"
DEFAULT_PORT = 9876
_OFF_VALUES = ("off", "0", "false", "no")


class RerunError(PrsmError, RuntimeError):
    """The Rerun output could not be started (e.g. no viewer to spawn)."""


CLOSE_TIMEOUT_S = 10.0  # default wait in close() for the background thread, then again for the flush
# The background thread turns a batch's rows into columns in Python (each row's derived outputs and,
# for the loads, its internal vector: 10-40 µs a row on the 2-core VM) while holding the GIL, which
# a 1 kHz loop woken on its deadline then waits for: up to the switch interval (5 ms by default) per
# hand-over. So it converts ROWS_PER_SLICE rows at a time and sleeps YIELD_S between slices (a real
# sleep: `sleep(0)` lets the releasing thread win the race to re-take the GIL), which bounds the
# loop's wait near one slice; `BatchedStream` does the same between entities. The node's realtime
# mode hands the lock over after 100 µs, but the loop still waits that long and longer behind a native
# call that holds the lock: without the sleeps the loop's lateness p99 beside the sink was above 1 ms
# in 3 of 7 runs, with them in 1 of 9 (fu2018 at 1 kHz, 2-core VM, the loop of `prsm-bench --only rerun`),
# for about 2 % of a core more.
ROWS_PER_SLICE = 16
FLUSH_PERIOD_S = 0.2  # default period of the scalar outputs' sends (module docstring)
SCENE_RATE_HZ = 30.0  # default rate of the 3-D scene's frames, of simulation time
LOADS_PERIOD_S = 1.0  # default period of the internal loads' series and the 3-D scene (module docstring)
# default simulation-time rate of the internal loads' samples (module docstring): a multiple of the
# scene's default 30 Hz, so each scene frame is one of the samples and adds no row of its own
LOADS_RATE_HZ = 120.0
YIELD_S = 5e-5


def rerun_forced_off() -> bool:
    """True when the environment variable RERUN turns Rerun off."""
    return os.environ.get("RERUN", "").strip().lower() in _OFF_VALUES


def default_rrd_path(now: datetime | None = None) -> Path:
    """./prsm_<UTC yyyymmdd_HHMMSS>.rrd, the name `save` uses for an empty target (like the MCAP default)."""
    now = now or datetime.now(timezone.utc)
    return Path.cwd() / f"prsm_{now.strftime('%Y%m%d_%H%M%S')}.rrd"


def grpc_url(target: str) -> str:
    """A viewer address from `rerun+http://host:port/proxy`, `host:port`, a port or "" (the default viewer)."""
    t = target.strip()
    if not t:
        return f"rerun+http://127.0.0.1:{DEFAULT_PORT}/proxy"
    if "://" in t:
        if not t.startswith(("rerun://", "rerun+http://", "rerun+https://")) or not t.rstrip("/").endswith("/proxy"):
            raise ParamError(f"rerun_target {target!r}: a viewer URL must be rerun+http://HOST:PORT/proxy "
                             "(or rerun:// / rerun+https://)")
        return t
    host, _, port = t.rpartition(":")
    if not port.isdigit() or not 0 < int(port) < 65536:
        raise ParamError(f"rerun_target {target!r}: expected rerun+http://HOST:PORT/proxy, HOST:PORT or a port 1-65535")
    return f"rerun+http://{host or '127.0.0.1'}:{int(port)}/proxy"


def _spawn_port(target: str) -> int:
    t = target.strip()
    if not t:
        return DEFAULT_PORT
    if not t.isdigit() or not 0 < int(t) < 65536:
        raise ParamError(f"rerun_target {target!r}: in spawn mode the target is the viewer's port (1-65535) or empty")
    return int(t)


def _save_path(target: str) -> Path:
    path = Path(target).expanduser() if target.strip() else default_rrd_path()
    if path.is_dir():
        raise ParamError(f"rerun_target {target!r} is a directory; give a file name ending in .rrd")
    if not path.parent.is_dir():
        raise ParamError(f"rerun_target {target!r}: directory {str(path.parent)!r} does not exist")
    if not os.access(path.parent, os.W_OK):
        raise ParamError(f"rerun_target {target!r}: directory {str(path.parent)!r} is not writable")
    return path


def loads_sample_rows(time_s: np.ndarray, loads_rate_hz: float | None, scene_rate_hz: float,
                      slots: tuple[int, int]) -> tuple[np.ndarray, tuple[int, int]]:
    """Rows of a batch of steps (ending at `time_s`, s) whose internal loads the live view sends: the
    first step of each 1/loads_rate_hz and of each 1/scene_rate_hz of simulation time (so every scene
    frame is among them), or every row for `loads_rate_hz` None.

    `slots` are the last row's slots at the two rates (`scene.scene_frame_indices`; (-1, -1) to
    start): pass the returned ones back with the next batch, so a stream cut into batches anywhere
    is sampled like the whole.
    """
    if loads_rate_hz is None:
        return np.arange(len(time_s)), slots
    from prsm_ros.viz.scene import scene_frame_indices
    loads, loads_slot = scene_frame_indices(time_s, loads_rate_hz, slots[0])
    frames, frame_slot = scene_frame_indices(time_s, scene_rate_hz, slots[1])
    return np.union1d(loads, frames), (loads_slot, frame_slot)


class RecordingWriter:
    """One Rerun recording of a PRSM run: static scene, batches of steps, default blueprint.

    Shared by the live sink and `bag_to_rrd`, so a recording made live and one converted from a
    bag have the same entities. `params=None` means no geometry is known: series only.
    """

    def __init__(self, rec: Any, params: Params | None, layout: InternalLayout, model_name: str, *,
                 scalar_names: Iterable[str] = tuple(n for n, _ in OUTPUT_FIELDS),
                 scene_rate_hz: float = SCENE_RATE_HZ, yield_s: float = 0.0) -> None:
        from prsm_ros.viz import scene as rerun_scene, series as rerun_series
        if not (np.isfinite(scene_rate_hz) and scene_rate_hz > 0):
            raise ParamError(f"scene_rate_hz = {scene_rate_hz!r}: must be a finite number > 0")
        from prsm_ros.viz.columns import BatchedStream
        # a batch's columns go out in few calls: the cost is per call
        self.rec: Any = BatchedStream(rec, yield_s=yield_s)
        self.params = params
        self.layout = layout
        self.model_name = model_name
        self.scene_rate_hz = float(scene_rate_hz)
        self.scalar_names = [n for n in scalar_names if n != "time_s"]
        self._series = rerun_series
        self.scene = rerun_scene.Scene(params, layout) if params is not None else None
        self._slot = -1
        self.rows = 0
        self.scene_frames = 0
        self.inputs: list[str] = []

    def log_static(self) -> None:
        s = self._series
        s.log_series_styles(self.rec, s.series_entities(self.scalar_names, self.layout))
        if self.scene is not None:
            self.scene.log_static(self.rec)

    def send(self, columns: Mapping[str, np.ndarray], internal: np.ndarray | None, *, scalars: bool = True,
             loads: bool = True) -> None:
        """A batch of consecutive steps: every step to the series, the scene at its rate.

        `scalars`: the scalar outputs' series; `loads`: the internal loads' series and the scene
        (the live sink sends the two at their own periods; a bag's conversion sends both).
        """
        n = len(columns["time_s"])
        if scalars:
            self.rows += self._series.send_scalars(self.rec, columns)
        if loads and n:
            self._series.send_blocks(self.rec, columns["time_s"], internal, self.layout)
            if self.scene is not None:
                from prsm_ros.viz.scene import scene_frame_indices
                idx, self._slot = scene_frame_indices(columns["time_s"], self.scene_rate_hz, self._slot)
                if len(idx):
                    cols = {k: np.asarray(v)[idx] for k, v in columns.items()}
                    self.scene_frames += self.scene.send_frames(self.rec, cols,
                                                                None if internal is None else internal[idx])
        self.rec.flush_columns()

    def send_input(self, name: str, time_s: np.ndarray, values: np.ndarray, unit: str = "") -> None:
        """A recorded input (e.g. the controller's nut position reference), plotted beside the outputs."""
        if name not in self.inputs:
            self._series.log_input_style(self.rec, name, unit)
            self.inputs.append(name)
        self._series.send_input(self.rec, name, time_s, values, unit)
        self.rec.flush_columns()

    def blueprint(self):
        from prsm_ros.viz.blueprint import default_blueprint
        eye = 3 * self.params.geometry.nut_radius_m if self.params is not None else None
        return default_blueprint(self.scalar_names, self.layout, scene=self.scene is not None, inputs=self.inputs,
                                 eye_distance_m=eye)

    def send_blueprint(self) -> None:
        """Make the default layout active, so the file or viewer opens laid out whatever the viewer remembers."""
        self.rec.send_blueprint(self.blueprint(), make_active=True, make_default=True)


class RerunSink:
    """Live Rerun output of the node (contract: mode, target, params, layout, model_name, scene_rate_hz).

    Bad mode or target raises ValueError naming what is allowed; nothing is started then.
    """

    def __init__(self, mode: str, target: str, params: Params, layout: InternalLayout, model_name: str, *,
                 scene_rate_hz: float = SCENE_RATE_HZ, flush_period_s: float = FLUSH_PERIOD_S,
                 loads_period_s: float | None = None, loads_rate_hz: float | None = LOADS_RATE_HZ,
                 queue_size: int = 100_000, recording_name: str | None = None) -> None:
        if mode not in MODES:
            raise ParamError(f"rerun = {mode!r}: must be one of {', '.join(MODES)}")
        if not (isinstance(flush_period_s, (int, float)) and 0 < flush_period_s <= 10):
            raise ParamError(f"flush_period_s = {flush_period_s!r}: must be in (0, 10] s")
        if loads_period_s is None:
            loads_period_s = max(LOADS_PERIOD_S, flush_period_s)
        if not (isinstance(loads_period_s, (int, float)) and flush_period_s <= loads_period_s <= 60):
            raise ParamError(f"loads_period_s = {loads_period_s!r}: must be in [flush_period_s = {flush_period_s!r}, "
                             "60] s")
        if loads_rate_hz is not None and not (isinstance(loads_rate_hz, (int, float)) and 0 < loads_rate_hz < math.inf):
            raise ParamError(f"loads_rate_hz = {loads_rate_hz!r}: must be a finite number > 0 (Hz of simulation "
                             "time), or None for every step")
        if not (isinstance(queue_size, int) and queue_size > 0):
            raise ParamError(f"queue_size = {queue_size!r}: must be a whole number > 0")
        self.requested_mode = mode
        self.mode = "off" if rerun_forced_off() else mode
        self.target = target
        self.layout = layout
        self.model_name = model_name
        self.flush_period_s = float(flush_period_s)
        self.loads_period_s = float(loads_period_s)
        self.loads_rate_hz = None if loads_rate_hz is None else float(loads_rate_hz)
        self.scene_rate_hz = float(scene_rate_hz)
        self._slots = (-1, -1)  # the last step's slot at loads_rate_hz and at scene_rate_hz (`scene_frame_indices`)
        self._pending: list[tuple[list[Outputs], dict[str, np.ndarray]]] = []  # sent as scalars, loads not yet
        self._loads_due = 0.0
        self.queue_size = queue_size
        self.path: Path | None = None
        self.url: str | None = None
        self.error: str | None = None
        self.dropped = 0  # queue full (caller's thread only)
        self._lost_lock = threading.Lock()  # `lost` is counted by the background thread and by a timed-out close
        self.lost = 0  # queued steps discarded after a Rerun failure or an unfinished close
        self.submitted = 0
        self.batches = 0
        self.flush_time_s = 0.0  # wall time the background thread spent on batches
        self._queue: deque[Outputs] = deque()
        self._inputs: deque[tuple[str, float, float, str]] = deque()  # (name, time s, value, unit)
        self._closed = False
        self._thread: threading.Thread | None = None
        self._wake = threading.Event()
        self.writer: RecordingWriter | None = None
        if self.mode == "off":
            return
        # validate the target before importing or starting anything
        port = None
        if self.mode == "save":
            self.path = _save_path(target)
        elif self.mode == "connect":
            self.url = grpc_url(target)
        else:
            port = _spawn_port(target)
        import rerun as rr
        existed = self.path is not None and self.path.exists()
        rec = rr.RecordingStream(APPLICATION_ID, recording_id=uuid.uuid4())
        try:
            self._start(rec, params, layout, model_name, scene_rate_hz, recording_name, port)
        except BaseException:
            # nothing may outlive a failed start: no stream holding the file or the socket, no thread,
            # and no half-written .rrd of a run that never happened (the node's recorder does the same)
            self.writer = None
            self._closed = True
            try:
                rec.disconnect()
            except Exception:
                pass  # the start-up error is the one to report
            if self.path is not None and not existed:
                self.path.unlink(missing_ok=True)
            raise
        atexit.register(self.close)  # a script that forgets close() still gets a finished file

    def _start(self, rec: Any, params: Params, layout: InternalLayout, model_name: str, scene_rate_hz: float,
               recording_name: str | None, port: int | None) -> None:
        """Open the sink (file, viewer or connection), send the recording's static part, start the thread."""
        self.writer = RecordingWriter(rec, params, layout, model_name, scene_rate_hz=scene_rate_hz, yield_s=YIELD_S)
        if self.mode == "save":
            rec.save(self.path)
        elif self.mode == "connect":
            rec.connect_grpc(self.url)
        else:
            try:
                rec.spawn(port=port, hide_welcome_screen=True)
            except Exception as e:  # no viewer binary, no display: say so, the caller decides
                raise RerunError(f"rerun = spawn: could not start a viewer on port {port} ({e}); "
                                   "use rerun = save or connect instead") from None
            self.url = f"rerun+http://127.0.0.1:{port}/proxy"
        rec.send_recording_name(recording_name or f"{params.name} · {model_name}")
        self.writer.send_blueprint()
        self.writer.log_static()
        self._thread = threading.Thread(target=self._run, name="prsm-rerun-sink", daemon=True)
        self._thread.start()

    @property
    def active(self) -> bool:
        return self.writer is not None and not self._closed and self.error is None

    def submit(self, out: Outputs) -> None:
        """Queue one step's outputs (O(1), no lock, no Rerun call); dropped and counted when the queue is full."""
        if self.writer is None or self._closed or self.error is not None:
            return
        if len(self._queue) >= self.queue_size:
            self.dropped += 1
            return
        self._queue.append(out)
        self.submitted += 1

    def submit_input(self, name: str, time_s: float, value: float, unit: str = "") -> None:
        """Queue one sample of an input the run does not output (the controller's nut position reference),
        plotted beside the outputs at its own time as `bag_to_rrd` does; O(1), bounded like `submit`."""
        if self.writer is None or self._closed or self.error is not None:
            return
        if len(self._inputs) >= self.queue_size:
            self.dropped += 1
            return
        self._inputs.append((name, float(time_s), float(value), unit))

    def submit_reference(self, raw: bytes, joint: str) -> None:
        """A nut position reference as CDR bytes of a sensor_msgs/JointState (the node's
        `~/nut_position_reference`): `joint`'s position at the header stamp, the state it answers."""
        from prsm_ros.cdr_read import joint_state_position
        try:
            stamp_ns, x = joint_state_position(raw, joint)
        except (ValueError, IndexError, struct.error):
            return  # the recorder keeps what does not parse; the viewer has nothing to draw
        self.submit_input("nut_position_reference", stamp_ns * 1e-9, x, "m")

    def _drain_inputs(self) -> None:
        n = len(self._inputs)
        by_name: dict[tuple[str, str], tuple[list[float], list[float]]] = {}
        for _ in range(n):
            name, t, v, unit = self._inputs.popleft()
            ts, vs = by_name.setdefault((name, unit), ([], []))
            ts.append(t)
            vs.append(v)
        for (name, unit), (ts, vs) in by_name.items():
            self.writer.send_input(name, np.array(ts), np.array(vs), unit)

    def _drain(self, final: bool = False) -> None:
        if self._inputs and self.error is None:
            try:
                self._drain_inputs()
            except Exception as e:  # never propagate into the node: report and stop logging
                self.error = f"rerun logging failed: {type(e).__name__}: {e}"
        n = len(self._queue)
        if self.error is not None:
            return
        t0 = time.perf_counter()
        rows = [self._queue.popleft() for _ in range(n)]
        try:
            if n:
                columns = self._scalar_columns(rows)
                self.writer.send(columns, None, loads=False)
                keep = self._loads_rows(columns["time_s"])
                self._pending.append(([rows[i] for i in keep], {k: v[keep] for k, v in columns.items()}))
            if self._pending and (final or t0 >= self._loads_due):
                self._loads_due = t0 + self.loads_period_s
                self._send_loads()
        except Exception as e:  # never propagate into the node: report and stop logging
            self.error = f"rerun logging failed: {type(e).__name__}: {e}"
            self._count_lost(n + self._discard_queued())
        if n:
            self.batches += 1
        self.flush_time_s += time.perf_counter() - t0

    @staticmethod
    def _slices(rows: list[Outputs]):
        """The rows in slices of ROWS_PER_SLICE, the GIL handed back after each (the comment at ROWS_PER_SLICE)."""
        for i in range(0, len(rows), ROWS_PER_SLICE):
            yield rows[i:i + ROWS_PER_SLICE]
            time.sleep(YIELD_S)

    def _scalar_columns(self, rows: list[Outputs]) -> dict[str, np.ndarray]:
        """The rows' scalar outputs as columns (`_slices`)."""
        parts = [trajectory_from_rows(part, self.layout, State()).columns for part in self._slices(rows)]
        return parts[0] if len(parts) == 1 else {k: np.concatenate([c[k] for c in parts]) for k in parts[0]}

    def _loads_rows(self, time_s: np.ndarray) -> np.ndarray:
        """Indices of the steps (ending at `time_s`) whose internal loads are sent (`loads_sample_rows`)."""
        idx, self._slots = loads_sample_rows(time_s, self.loads_rate_hz, self.scene_rate_hz, self._slots)
        return idx

    def _send_loads(self) -> None:
        """The internal loads' series and the scene of the sampled steps sent as scalars since the last time."""
        pending, self._pending = self._pending, []
        rows = [r for rs, _ in pending for r in rs]
        if not rows:
            return
        columns = {k: np.concatenate([c[k] for _, c in pending]) for k in pending[0][1]}
        internal = None
        if self.layout.size:
            parts = [np.array([r.internal for r in part], dtype=float) for part in self._slices(rows)]
            internal = np.concatenate(parts).reshape(len(rows), self.layout.size)
        writer = self.writer
        assert writer is not None  # the background thread runs only on a started sink
        writer.send(columns, internal, scalars=False)

    def _run(self) -> None:
        while not self._wake.wait(self.flush_period_s):
            self._drain()
        self._drain(final=True)

    def _count_lost(self, n: int) -> None:
        with self._lost_lock:
            self.lost += n

    def _discard_queued(self) -> int:
        n = 0
        while True:
            try:
                self._queue.popleft()
            except IndexError:
                return n
            n += 1

    def close(self, timeout_s: float = CLOSE_TIMEOUT_S) -> bool:
        """Send what is queued, flush and close the file or connection; True when all went out cleanly.

        Each wait is bounded by `timeout_s`: the background thread's last batch, then Rerun's
        flush. A thread that does not finish in time (a stalled viewer connection) is left behind,
        what it had not taken is counted in `lost` and `error` says so; the stream is disconnected
        whatever happened before. Idempotent (later calls return the first's verdict).
        """
        if self._closed:
            return self.error is None
        self._closed = True  # submit() takes nothing from now on
        atexit.unregister(self.close)
        if self._thread is not None:
            self._wake.set()
            self._thread.join(timeout=timeout_s)
            if self._thread.is_alive():
                self._count_lost(self._discard_queued())
                self.error = self.error or (f"rerun sink: the background thread did not finish within {timeout_s:g} s; "
                                            f"{self.lost} steps were not sent")
        if self.writer is not None:
            rec = self.writer.rec
            try:
                rec.flush(timeout_sec=timeout_s)
            except Exception as e:
                self.error = self.error or f"rerun flush failed: {type(e).__name__}: {e}"
            finally:
                try:
                    rec.disconnect()
                except Exception as e:
                    self.error = self.error or f"rerun disconnect failed: {type(e).__name__}: {e}"
        return self.error is None

    def stats(self) -> dict[str, Any]:
        """Counters for diagnostics: steps submitted, dropped, rows and scene frames sent, batches, error."""
        w = self.writer
        return {"mode": self.mode, "submitted": self.submitted, "dropped": self.dropped, "lost": self.lost,
                "rows": w.rows if w else 0, "scene_frames": w.scene_frames if w else 0,
                "batches": self.batches, "flush_time_s": self.flush_time_s, "error": self.error}

    def __enter__(self) -> RerunSink:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
