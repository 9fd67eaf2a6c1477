"""Benchmarks of the MCAP recorder: throughput, and its cost beside a 1 kHz step loop.

- throughput: messages per second from the first `write` until `close()` returns (chunking, zstd,
  indexes, summary), for the node's per-step topics of a real run (joint states, wrench, internal
  loads of the model's layout, /clock, the torque command), handed over as the node hands them:
  CDR bytes from its encoder (`cdr_write.StepEncoder`), in one batch per step (`write_many`), to the
  recorder of the node's fast mode and the offline tools (`McapRecorder`, the writer in a thread) and,
  beside it, to the paced modes' (`McapProcessRecorder`: the writer in a child process, whose CPU is counted);
- peers of the throughput, same messages, same run: the native work alone (zstd and CRC-32 of the
  same chunks' bytes, what no Python writer can go below) and `foxglove-sdk`'s MCAP writer (native
  code; its files are not the recorder's bytes, see docs/bags.md);
- CPU at 1 kHz: a loop paced on absolute 1 ms deadlines that maps each step's outputs to the
  messages (as the node does) and records them, against the same loop without recording; the
  difference in CPU time per wall second (this process and its writer process) is the recorder's
  cost (% of one core), and the loop's lateness percentiles show whether the writer disturbs the
  step loop; the same with the thread recorder beside it, and with the internal loads recorded at
  100 Hz (the node's `record_internal_loads_rate:=100`: every topic but those every step); and the same
  loop with `foxglove-sdk`'s native writer in the step thread, its chunk finished at the recorder's flush
  interval: the cost of native code doing the same job here, the peer the CPU aim is restated against.

Figures are printed, never asserted (`prsm-bench` aggregates them).
"""

from __future__ import annotations

import contextlib
import functools
import statistics
import tempfile
import time
from pathlib import Path

from prsm_ros.bench.common import BenchError, area_main, cpu_with_children_s, figure, paced_loop

THROUGHPUT_TARGET = 100_000.0  # messages/s
CPU_TARGET_PCT = 5.0  # % of a core at 1 kHz
NATIVE_RATIO_TARGET = 1.5  # the recorder's CPU at 1 kHz over a native writer's in the same loop (the node's CPU aim's ratio)
DECIMATED_LOADS_EVERY = 10  # steps between two recorded internal loads in the decimated run (100 Hz at 1 kHz)


def _run_outputs(model: str, steps: int):
    """The recorded run: s30 reversing at the heavy scenario's load. The heavy scenario itself runs one way, and
    in the 10 s measured it drove the nut into its thread end (280 kN, past the static rating: a warning)."""
    from prsm_sim import Simulator, preset
    from prsm_sim.scenarios import HEAVY_LOAD_N, default_spec, run_scenario
    p = preset("s30")
    sim = Simulator(p, model, 1e-3)
    traj = run_scenario(sim, default_spec(p, "sine-motion", load_n=HEAVY_LOAD_N), steps * 1e-3)
    return p, traj


def _channels(rec):
    from std_msgs.msg import Float64

    from prsm_ros.messages import STEP_TOPICS, TOPICS
    topics = [TOPICS[k].resolved() for k in STEP_TOPICS]
    for k in STEP_TOPICS:
        rec.add_channel(TOPICS[k].resolved(), TOPICS[k].msg_class, TOPICS[k].qos)
    cmd = TOPICS["screw_torque"]
    rec.add_channel(cmd.resolved(), Float64, cmd.qos)
    return topics, cmd.resolved()


@functools.lru_cache(maxsize=2)
def prepared_steps(model: str, steps: int) -> list[tuple[int, list[bytes]]]:
    """`_step_bytes` of a `steps`-step run, built once per measurement (`measure` clears it)."""
    _, traj = _run_outputs(model, steps)
    return _step_bytes(traj, model)


def _step_bytes(traj, model: str) -> list[tuple[int, list[bytes]]]:
    """Each step's messages as the node records them: (stamp ns, [torque command, then STEP_TOPICS' CDR bytes])."""
    from rclpy.serialization import serialize_message
    from std_msgs.msg import Float64

    from prsm_ros.messages import STEP_TOPICS, MessageMapper, time_ns
    enc = MessageMapper(traj.layout, model).encoder()
    encode = {"joint_states": enc.joint_state, "wrench": enc.wrench,
              "internal_loads": lambda out, ns: enc.internal_loads(out), "clock": lambda out, ns: enc.clock(ns)}
    prepared = []
    for k in range(len(traj)):
        out = traj.row(k)
        ns = time_ns(out.time_s)
        prepared.append((ns, [serialize_message(Float64(data=out.screw_torque_nm)),
                              *(encode[key](out, ns) for key in STEP_TOPICS)]))
    return prepared


def _recorder(kind: str):
    """The node's recorder ("process") or the thread recorder of the offline tools ("thread")."""
    if kind == "process":
        from prsm_ros.mcap.recorder_process import McapProcessRecorder
        return McapProcessRecorder
    from prsm_ros.mcap.recorder import McapRecorder
    return McapRecorder


def throughput(model: str, steps: int, repeats: int, kind: str = "process") -> tuple[float, float, float, int, float]:
    """(median messages/s, spread, MB/s of file, messages per run, median messages per CPU second).

    Messages per CPU second (all threads, and the writer process) is what a busy machine changes
    least: the wall-clock rate there measures the share of a core the run got as much as the writer."""
    Recorder = _recorder(kind)
    prepared = prepared_steps(model, steps)
    rates, sizes, cpu_rates = [], [], []
    n_msgs = 0
    with tempfile.TemporaryDirectory() as d:
        for r in range(repeats + 1):  # run 0 warms up (imports, schema files, zstd) and is not counted
            path = Path(d) / f"t{r}.mcap"
            rec = Recorder(path, queue_size=10 * len(prepared) + 10)
            topics, cmd_topic = _channels(rec)
            t0, c0 = time.perf_counter(), cpu_with_children_s()
            for stamp, msgs in prepared:
                rec.write_many([(cmd_topic, msgs[0], stamp), *zip(topics, msgs[1:], [stamp] * len(topics), strict=True)])
            rec.close()
            wall, cpu = time.perf_counter() - t0, cpu_with_children_s() - c0
            n_msgs = rec.messages_written
            if rec.messages_dropped or rec.error:
                raise BenchError(f"benchmark run lost messages: dropped {rec.messages_dropped}, error {rec.error}")
            if r > 0:
                rates.append(n_msgs / wall)
                cpu_rates.append(n_msgs / cpu)
                sizes.append(path.stat().st_size / wall / 1e6)
    med = statistics.median(rates)
    return med, (max(rates) - min(rates)) / med, statistics.median(sizes), n_msgs, statistics.median(cpu_rates)


def native_floor(model: str, steps: int) -> float:
    """Messages per CPU second if only the native per-chunk work were done: zstd (mcap's level) and CRC-32
    of the uncompressed chunks the recorder wrote for the same messages (read back from its file)."""
    import zlib

    import zstandard
    from mcap.reader import make_reader

    from prsm_ros.mcap.recorder import McapRecorder

    prepared = prepared_steps(model, steps)
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "floor.mcap"
        with McapRecorder(path, queue_size=10 * len(prepared) + 10) as rec:
            topics, cmd_topic = _channels(rec)
            for stamp, msgs in prepared:
                rec.write_many([(cmd_topic, msgs[0], stamp), *zip(topics, msgs[1:], [stamp] * len(topics), strict=True)])
        n_msgs = rec.messages_written
        chunks = []
        with open(path, "rb") as f:
            reader = make_reader(f)
            for index in reader.get_summary().chunk_indexes:
                f.seek(index.chunk_start_offset)
                chunks.append(zstandard.decompress(_chunk_records(f.read(index.chunk_length)),
                                                   max_output_size=index.uncompressed_size))
    t0 = time.process_time()
    for data in chunks:
        zstandard.compress(data)
        zlib.crc32(data)
    return n_msgs / (time.process_time() - t0)


def _chunk_records(record: bytes) -> bytes:
    """The compressed records of one MCAP Chunk record (opcode, length, start, end, size, crc, compression, records)."""
    import struct
    (compression_len,) = struct.unpack_from("<I", record, 9 + 8 + 8 + 8 + 4)
    at = 9 + 8 + 8 + 8 + 4 + 4 + compression_len
    (records_len,) = struct.unpack_from("<Q", record, at)
    return record[at + 8:at + 8 + records_len]


@contextlib.contextmanager
def foxglove_writing(echo: bool = False, path: Path | None = None):
    """`foxglove-sdk`'s native MCAP writer on the recorded topics (same CDR bytes, channels, zstd, 1 MiB chunks) at
    `path`, or in a temporary directory: yields (writer, channels in a prepared step's order, then
    ~/command_echo's if `echo`), or None when the package is not installed. Their context is held until the block
    ends: once it is collected, its channels are closed and drop what they are given."""
    try:
        import foxglove
        from foxglove.mcap import MCAPCompression, MCAPWriteOptions
    except ImportError:
        yield None
        return
    from std_msgs.msg import Float64

    from prsm_ros.mcap import schema as mcap_schema
    from prsm_ros.messages import STEP_TOPICS, TOPICS
    topics = [(TOPICS["screw_torque"].resolved(), Float64, TOPICS["screw_torque"].qos)]
    topics += [(TOPICS[k].resolved(), TOPICS[k].msg_class, TOPICS[k].qos)
               for k in STEP_TOPICS + (("command_echo",) if echo else ())]
    with tempfile.TemporaryDirectory() as d:
        ctx = foxglove.Context()
        options = MCAPWriteOptions(compression=MCAPCompression.Zstd, profile=mcap_schema.PROFILE,
                                   chunk_size=1 << 20, compression_threads=0)
        writer = foxglove.open_mcap(path if path is not None else Path(d) / "fox.mcap", context=ctx,
                                    writer_options=options)
        channels = []
        for topic, cls, qos in topics:
            name = mcap_schema.type_name(cls)
            schema = foxglove.Schema(name=name, encoding=mcap_schema.SCHEMA_ENCODING,
                                     data=mcap_schema.full_definition(name).encode())
            channels.append(foxglove.Channel(
                topic, schema=schema, message_encoding=mcap_schema.MESSAGE_ENCODING, context=ctx,
                metadata={"offered_qos_profiles": mcap_schema.offered_qos_profiles_yaml(qos)}))
        try:
            yield writer, channels
        finally:
            writer.close()


def _log_step(channels, stamp: int, msgs: list[bytes]) -> None:
    """One prepared step's messages through the native writer's channels."""
    for channel, data in zip(channels, msgs, strict=True):
        channel.log(data, log_time=stamp)


def foxglove_peer(model: str, steps: int) -> float | None:
    """Messages per CPU second through `foxglove-sdk`'s native MCAP writer (`foxglove_writing`, one
    `Channel.log` per message, the summary written); None when the package is not installed."""
    prepared = prepared_steps(model, steps)
    with foxglove_writing() as opened:
        if opened is None:
            return None
        writer, channels = opened
        t0 = time.process_time()
        for stamp, msgs in prepared:
            _log_step(channels, stamp, msgs)
        writer.close()  # inside the timing, as the recorder's summary is (the block's close then does nothing)
        return len(prepared) * len(channels) / (time.process_time() - t0)


def foxglove_loop_cost(model: str, seconds: float) -> dict | None:
    """`loop_cost`'s loop with `foxglove-sdk`'s native writer in the step thread instead of the recorder, its
    chunk finished and flushed every `FLUSH_INTERVAL_S` of steps (the recorder's bound on what a SIGKILL
    loses): what a native writer costs at 1 kHz on this machine. None when the package is not installed."""
    from prsm_ros.mcap.recorder import FLUSH_INTERVAL_S
    steps = int(seconds * 1000)
    flush_every = max(int(round(FLUSH_INTERVAL_S * 1000)), 1)
    prepared = prepared_steps(model, steps)
    with foxglove_writing() as opened:
        if opened is None:
            return None
        writer, channels = opened

        def step(k: int) -> None:
            _log_step(channels, *prepared[k])
            if k % flush_every == flush_every - 1:
                writer.flush()

        return paced_loop(steps, step)


def loop_cost(model: str, seconds: float, record: str | None, loads_every: int = 1) -> dict:
    """A 1 kHz loop mapping (and optionally recording: `record` "process" or "thread") each step's messages,
    as the node does; the internal loads only every `loads_every`-th step (`record_internal_loads_rate`)."""
    from prsm_ros.messages import STEP_TOPICS
    steps = int(seconds * 1000)
    prepared = prepared_steps(model, steps)
    loads = 1 + STEP_TOPICS.index("internal_loads")  # its place in a prepared step (the command first)
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "loop.mcap"
        rec = _recorder(record)(path) if record else None
        topics, cmd_topic = _channels(rec) if rec is not None else ([], "")

        def step(k: int) -> None:
            stamp, msgs = prepared[k]
            if rec is not None:
                items = [(cmd_topic, msgs[0], stamp), *zip(topics, msgs[1:], [stamp] * len(topics), strict=True)]
                if k % loads_every:
                    del items[loads]
                rec.write_many(items)

        result = paced_loop(steps, step)
        if rec is not None:
            rec.close()  # after the measurement: the tail's flush is not part of the steady-state cost
        result.update(written=rec.messages_written if rec else 0, dropped=rec.messages_dropped if rec else 0,
                      file_bytes=path.stat().st_size if rec else 0)
    return result


def measure(quick: bool = False) -> list[dict]:
    from prsm_sim import MODELS

    from prsm_ros.mcap.recorder import FLUSH_INTERVAL_S
    model = "fu2018" if "fu2018" in MODELS else "jones2016"
    steps = 2000 if quick else 10_000
    # in batch (the node's fast mode) the writer is the thread; paced (realtime, lockstep) the process
    rate, spread, mb_s, n, cpu_rate = throughput(model, steps, 1 if quick else 5, kind="thread")
    p_rate, _, _, _, p_cpu_rate = throughput(model, steps, 1 if quick else 3, kind="process")
    floor = native_floor(model, steps)
    fox = foxglove_peer(model, steps)
    seconds = 1.0 if quick else 10.0
    base = loop_cost(model, seconds, record=None)
    rec = loop_cost(model, seconds, record="process")
    thread = loop_cost(model, seconds, record="thread")
    decimated = loop_cost(model, seconds, record="process", loads_every=DECIMATED_LOADS_EVERY)
    native = foxglove_loop_cost(model, seconds)
    cost = (rec["cpu_per_wall"] - base["cpu_per_wall"]) * 100
    native_cost = None if native is None else (native["cpu_per_wall"] - base["cpu_per_wall"]) * 100
    native_ratio = None if native_cost is None or native_cost <= 0 else cost / native_cost
    decimated_cost = (decimated["cpu_per_wall"] - base["cpu_per_wall"]) * 100
    thread_cost = (thread["cpu_per_wall"] - base["cpu_per_wall"]) * 100
    per_s = rec["written"] / seconds
    prepared_steps.cache_clear()
    fox_note = "not installed" if fox is None else f"{fox:,.0f}"
    return [
        figure(f"MCAP recorder throughput ({model} topics, 5 per step)", rate, "msg/s", f"≥ {THROUGHPUT_TARGET:.0f}",
               rate >= THROUGHPUT_TARGET, spread,
               f"{n} messages per run, {mb_s:.1f} MB/s of file, zstd chunks + indexes, the fast mode's recorder (the "
               f"writer thread); per CPU second: {cpu_rate:,.0f}, beside zstd + CRC of the same chunks alone "
               f"{floor:,.0f} and foxglove-sdk's native writer {fox_note}; the paced modes' recorder (writer process) "
               f"{p_rate:,.0f} msg/s, {p_cpu_rate:,.0f} per CPU second (itself and its process)"),
        figure("MCAP recorder messages per CPU second over its native floor (zstd + CRC alone)", cpu_rate / floor, "×",
               "(peer)", None, None,
               f"foxglove-sdk's writer over the same floor: {'n/a' if fox is None else f'{fox / floor:.2f}×'}"),
        figure("MCAP recorder CPU at 1 kHz, all topics", cost, "% core", f"≤ {CPU_TARGET_PCT:g}", cost <= CPU_TARGET_PCT,
               None, f"{per_s:.0f} msg/s recorded; loop alone {base['cpu_per_wall'] * 100:.1f} % of a core, "
                     f"with the node's recorder {rec['cpu_per_wall'] * 100:.1f} % (this process and its writer "
                     f"process); dropped {rec['dropped']}; the native floor (zstd + CRC) at this rate "
                     f"{per_s / floor * 100:.1f} % of a core; the thread recorder {thread_cost:.1f} %; "
                     f"foxglove-sdk's native writer in the step thread of the same loop "
                     f"{'not installed' if native_cost is None else f'{native_cost:.1f} %'}"),
        figure("MCAP recorder CPU at 1 kHz over foxglove-sdk's native writer in the same loop", native_ratio, "×",
               f"≤ {NATIVE_RATIO_TARGET:g}", None if native_ratio is None else native_ratio <= NATIVE_RATIO_TARGET,
               None, "the same messages at 1 kHz, the native writer logging each in the step thread and finishing its "
                     f"chunk every {FLUSH_INTERVAL_S * 1e3:g} ms of steps (the recorder's flush interval): where it costs more than "
                     f"{CPU_TARGET_PCT:g} % of a core, that aim is below what native code does here, and this ratio "
                     f"is the aim restated; its loop lateness p99 "
                     f"{'n/a' if native is None else format(native['late_p99_ms'], '.3f')} ms"),
        figure(f"MCAP recorder CPU at 1 kHz, internal loads every {DECIMATED_LOADS_EVERY}th step", decimated_cost,
               "% core", f"≤ {CPU_TARGET_PCT:g}", decimated_cost <= CPU_TARGET_PCT, None,
               f"the node's record_internal_loads_rate:={1000 / DECIMATED_LOADS_EVERY:g} (every other topic every "
               f"step); {decimated['written'] / seconds:.0f} msg/s recorded, the file "
               f"{decimated['file_bytes'] / max(rec['file_bytes'], 1):.2f}× the size of the one with every step's; "
               f"dropped {decimated['dropped']}; same loop alone as above"),
        figure("1 kHz loop lateness p99 with recorder", rec["late_p99_ms"], "ms", "≤ 1", rec["late_p99_ms"] <= 1.0, None,
               f"without recorder p99 {base['late_p99_ms']:.3f} ms; p50 {rec['late_p50_ms']:.3f} vs {base['late_p50_ms']:.3f} ms; "
               f"max {rec['late_max_ms']:.2f} vs {base['late_max_ms']:.2f} ms (OS scheduling on a shared machine shows here too); "
               f"with the thread recorder p99 {thread['late_p99_ms']:.3f} ms"),
    ]


def main(argv: list[str] | None = None) -> int:
    return area_main("recorder", measure, argv)


if __name__ == "__main__":
    raise SystemExit(main())
