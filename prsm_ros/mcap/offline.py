"""Offline runs to MCAP without DDS: the same topics and messages a node run records.

`write_trajectory_mcap` maps each step of a `Trajectory` through `interface.MessageBuilder` (the
node's own mapping) and writes it with `recorder.McapFile`, so a bag from `prsm-sim run --mcap`
and one from `prsm-node` read the same. No ROS package is needed: the messages are a rosbags
typestore's and `codec.TypestoreCodec` serializes and describes them (the same CDR bytes and type
hashes as rclpy's; see `prsm_ros.mcap.codec`). Per step (stamped with the step's end time, as the node
stamps its outputs): `/joint_states`, `~/nut/wrench`, `~/internal_loads`, `/clock`; the applied
torque as the `~/screw_torque` command the node would have received, stamped at the step's start
(the simulation time at which the node takes a command); once at t = 0 the latched labels; and,
when given, the controller's reference on `~/nut_position_reference` (stamped with the state it
answers, the step's start). `/diagnostics` (wall-clock
health of a live node) has no meaning offline and is not written.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from prsm_sim.errors import InputError

from prsm_ros.mcap.recorder import McapFile, run_metadata


def write_trajectory_mcap(path, traj, params, model_name: str, *, preset_name: str, progress: bool = True,
                          dt_s: float | None = None, reference_m=None,
                          extra_metadata: dict[str, dict[str, str]] | None = None,
                          ros_distro: str | None = None, chunk_size: int | None = None) -> Path:
    """Write `traj` (from `Simulator.run` or collected steps) as a ROS 2 MCAP file; returns the path.

    `dt_s`: the step (inferred from the time column when omitted). `reference_m`: optional nut
    position reference per step (m), recorded as a controller under test would publish it.
    `extra_metadata`: more MCAP metadata records, e.g. a scenario description. `ros_distro`: whose
    message definitions to write (default: `codec.typestore_distro()`). `chunk_size`: bytes per chunk
    before compression (default the recorder's).
    """
    from tqdm import tqdm

    from prsm_ros.interface import STEP_TOPICS, TOPIC_DEFS, MessageBuilder, time_ns
    from prsm_ros.mcap.codec import TypestoreCodec

    n = len(traj)
    t = np.asarray(traj["time_s"], dtype=float)
    if dt_s is None:
        if n == 0:
            raise InputError("an empty trajectory needs dt_s to describe the run")
        dt_s = float(t[1] - t[0]) if n > 1 else float(t[0])
    if reference_m is not None:
        reference_m = np.asarray(reference_m, dtype=float)
        if reference_m.shape != (n,):
            raise InputError(f"reference_m has shape {reference_m.shape}; expected ({n},), one value per step")
    codec = TypestoreCodec(ros_distro)
    mapper = MessageBuilder(traj.layout, model_name, codec.classes, codec.float_array)
    metadata = run_metadata(params, preset=preset_name, model=model_name, dt_s=dt_s)
    metadata.update(extra_metadata or {})
    path = Path(path)
    f = McapFile(path, metadata=metadata, codec=codec,
                 **({} if chunk_size is None else {"chunk_size": chunk_size}))
    try:
        keys = ("labels", "screw_torque", *STEP_TOPICS) + (("nut_position_reference",) if reference_m is not None else ())
        ids = {key: f.add_channel(TOPIC_DEFS[key].resolved(), codec.classes[TOPIC_DEFS[key].type_name],
                                  TOPIC_DEFS[key].qos)
               for key in keys}
        f.write(ids["labels"], mapper.labels(), 0)
        step_ids = [ids[k] for k in STEP_TOPICS]
        torque = np.asarray(traj["screw_torque_nm"], dtype=float)
        for k in tqdm(range(n), desc=f"writing {path.name}", unit="step", disable=(not progress) or None,
                      mininterval=0.5):
            out = traj.row(k)
            stamp = time_ns(out.time_s)
            command_stamp = time_ns(max(out.time_s - dt_s, 0.0))
            batch = [(ids["screw_torque"], mapper.float64(torque[k]), command_stamp)]
            if reference_m is not None:  # it answers the state at the step's start
                batch.append((ids["nut_position_reference"], mapper.reference(command_stamp, reference_m[k]),
                              command_stamp))
            batch += [(cid, msg, stamp) for cid, (_, msg) in zip(step_ids, mapper.messages(out), strict=False)]
            f.write_many(batch)
        f.finish()
    except BaseException:
        f.abort()
        raise
    return path
