"""The node's outputs besides DDS: the MCAP recording, the live Rerun view and the live Foxglove server,
opened from the configuration.

All are optional and imported only when asked for (the recorder needs mcap, the sink rerun-sdk,
the server foxglove-sdk). A refusal (a path not writable, a bad Rerun target, a port taken) is a
`ConfigError` naming the parameter; a refused start leaves no empty bag behind.
"""

from __future__ import annotations

from prsm_sim import InternalLayout

from prsm_ros.node.parameters import ConfigError, NodeConfig, physics_parameters
from prsm_ros.node.record_path import RecordPathError, claim_record_path


def open_sinks(cfg: NodeConfig, node_name: str, channels: dict, layout: InternalLayout):
    """(recorder, Rerun sink, Foxglove server), each None when off, for `cfg`; `channels` maps each
    topic name to (message class, QoS profile, untrusted), recorded and served as the node offers or
    requests them."""
    recorder = open_recorder(cfg, node_name, channels)
    try:
        return recorder, open_rerun(cfg, layout), open_foxglove(cfg, node_name, channels)
    except BaseException:
        if recorder is not None:  # no run happened: leave no empty bag behind
            recorder.close()
            recorder.path.unlink(missing_ok=True)
        raise


def open_recorder(cfg: NodeConfig, node_name: str, channels: dict):
    """The MCAP recorder at `record_path` (a directory or a {node} pattern claims a fresh file), or None."""
    if not cfg.record:
        return None
    from prsm_ros.mcap.recorder import McapRecorder, run_metadata
    node_params = {**cfg.values, **physics_parameters(cfg.params)}
    meta = run_metadata(cfg.params, preset=cfg.preset, model=cfg.model, dt_s=cfg.dt_s, node_parameters=node_params)
    try:
        path = claim_record_path(cfg.record_path, node_name)
    except RecordPathError as e:
        raise ConfigError(f"parameter record_path = {cfg.record_path!r}: {e}") from None
    rec = McapRecorder(path, metadata=meta, deterministic=cfg.time_mode == "lockstep")  # lockstep: golden bytes
    if rec.error:
        rec.close()
        raise ConfigError(f"parameter record_path = {cfg.record_path!r}: {rec.error}")
    for name, (msg_class, qos, untrusted) in channels.items():  # untrusted: bytes from other participants
        rec.add_channel(name, msg_class, qos, untrusted=untrusted)
    return rec


def open_rerun(cfg: NodeConfig, layout: InternalLayout):
    """The live Rerun sink, or None (parameter rerun off, or the RERUN environment variable turns it off)."""
    from prsm_ros.viz.sink import RerunSink, rerun_forced_off
    if cfg.rerun == "off" or rerun_forced_off():
        return None
    try:
        return RerunSink(cfg.rerun, cfg.rerun_target, cfg.params, layout, cfg.model)
    except (ValueError, RuntimeError) as e:
        raise ConfigError(str(e)) from None


def open_foxglove(cfg: NodeConfig, node_name: str, channels: dict):
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
    return live
