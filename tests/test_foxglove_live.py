"""The live Foxglove view: a WebSocket client speaking the Foxglove protocol receives /joint_states from
a running node (`-p foxglove_port:=N`) and from `prsm-bag serve`.

Oracles: the protocol as the Foxglove WebSocket spec states it (foxglove/ws-protocol, spec.md:
serverInfo and advertise as JSON text, a `subscribe` op, binary Message Data = opcode 0x01,
uint32 subscription id, uint64 log time, payload; binary Time = opcode 0x02); the payload
decoded with the schema text the server advertised, by mcap_ros2's independent ros2msg/CDR
decoder (what Foxglove runs); for `serve`, the bag's own bytes for the same message. The SDK's
server accepts the protocol under its current subprotocol name, `foxglove.sdk.v1`, only; the
client offers it and the original `foxglove.websocket.v1`.
"""

from __future__ import annotations

import asyncio
import json
import os
import re
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path

import pytest

from prsm_ros.ros_env import isolated_env

from ros_procs import CEILING_FACTOR, NodeProcess, ros_test_env

websockets = pytest.importorskip("websockets")

pytestmark = pytest.mark.slow  # node and bag-server processes over loopback (about 30 s)

ROOT = Path(__file__).resolve().parents[1]
ENV = ros_test_env("test_foxglove_live")
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
MESSAGE_DATA = 0x01
TIME = 0x02  # the server's clock (Time capability: `prsm-bag serve`)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


async def _receive(url: str, topic: str, n: int, timeout_s: float) -> tuple[dict, list[tuple[int, bytes]], dict]:
    """(the channel advertised for `topic`, n (log time, payload) received on it, serverInfo); connects as
    soon as the server listens."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            ws = await websockets.connect(url, subprotocols=SUBPROTOCOLS, open_timeout=5)
            break
        except (OSError, websockets.exceptions.InvalidHandshake, asyncio.TimeoutError):
            if time.monotonic() > deadline:
                raise
            await asyncio.sleep(0.1)
    async with ws:
        info, channel, got = None, None, []
        while len(got) < n:
            m = await asyncio.wait_for(ws.recv(), timeout=max(deadline - time.monotonic(), 0.1))
            if isinstance(m, str):
                d = json.loads(m)
                if d["op"] == "serverInfo":
                    info = d
                elif d["op"] == "advertise" and channel is None:
                    channel = next((c for c in d["channels"] if c["topic"] == topic), None)
                    if channel is not None:
                        await ws.send(json.dumps({"op": "subscribe",
                                                  "subscriptions": [{"id": 7, "channelId": channel["id"]}]}))
                continue
            if m[0] == TIME:
                continue
            assert m[0] == MESSAGE_DATA
            sub_id, log_time = struct.unpack_from("<IQ", m, 1)
            assert sub_id == 7
            got.append((log_time, bytes(m[13:])))
    return channel, got, info


def receive(url: str, topic: str, n: int = 5, timeout_s: float = 20.0):
    return asyncio.run(_receive(url, topic, n, timeout_s * CEILING_FACTOR))


def decode(channel: dict, payload: bytes):
    from mcap_ros2._dynamic import generate_dynamic
    return generate_dynamic(channel["schemaName"], channel["schema"])[channel["schemaName"]](payload)


def test_node_serves_joint_states_live(tmp_path):
    port = _free_port()
    params = {"record": False, "foxglove_port": port, "time_mode": "fast", "cmd_timeout": 0.0}
    with NodeProcess(ENV, params, workdir=tmp_path / "node") as proc:
        try:
            channel, got, info = receive(f"ws://127.0.0.1:{port}", "/joint_states", n=5)
            # a latched topic, published at start-up before this client came: sent again on subscribing
            desc_channel, desc, _ = receive(f"ws://127.0.0.1:{port}", "/robot_description", n=1)
        finally:
            code = proc.stop()
        assert code == 0, proc.stderr
    assert channel["encoding"] == "cdr" and channel["schemaEncoding"] == "ros2msg"
    assert channel["schemaName"] == "sensor_msgs/msg/JointState"
    assert info["name"].endswith("prsm_actuator")
    for log_time, payload in got:
        msg = decode(channel, payload)
        assert list(msg.name) == ["screw_joint", "nut_joint"]
        assert len(msg.position) == 2
        assert msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec == log_time  # stamped in sim time
    assert decode(desc_channel, desc[0][1]).data.startswith("<?xml")
    times = [t for t, _ in got]
    assert times == sorted(times) and len(set(times)) == len(times)


def test_node_refuses_a_taken_port(tmp_path):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        params = {"record": False, "foxglove_port": port}
        with NodeProcess(ENV, params, workdir=tmp_path / "node") as proc:
            code = proc.wait()
    assert code != 0
    assert "foxglove_port" in proc.stderr and "in use" in proc.stderr


def test_bag_serve_sends_the_bags_bytes(tmp_path):
    from prsm_ros.bag.reader import open_bag
    bag_path = ROOT / "bags" / "step_response.mcap"
    env = isolated_env(0, respect_user=False, PYTHONPATH=os.environ.get("PYTHONPATH", str(ROOT)))
    proc = subprocess.Popen([sys.executable, "-m", "prsm_ros.cli.bag", "serve", str(bag_path), "--port", "0",
                             "--rate", "50"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        line = proc.stdout.readline()
        url = re.search(r"ws://[\d.]+:\d+", line)
        assert url, line + proc.stderr.read() if proc.poll() is not None else line
        channel, got, _ = receive(url.group(0), "/joint_states", n=10)
        out, err = proc.communicate(timeout=60 * CEILING_FACTOR)  # one pass of a 1 s bag at ×50, then exit
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    assert "pass 1" in out
    expected = [(m.log_time_ns, m.data) for m in open_bag(bag_path).messages(["/joint_states"], decode=False)][:10]
    assert got == expected  # playback starts at the first subscription: nothing missed, the bag's own bytes
    assert list(decode(channel, got[0][1]).name) == ["screw_joint", "nut_joint"]


def test_bag_serve_refuses_bad_input_in_one_line(capsys):
    from prsm_ros.cli import bag
    bag_path = str(ROOT / "bags" / "step_response.mcap")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        taken = str(s.getsockname()[1])
        for args, why in ((["--rate", "0"], "--rate 0.0: must be a number > 0"),
                          (["--port", "70000"], "--port 70000: must be 0..65535"),
                          (["--port", taken], "in use")):
            assert bag.main(["serve", bag_path, *args]) == 2
            err = capsys.readouterr().err
            assert err.count("\n") == 1 and why in err, err
