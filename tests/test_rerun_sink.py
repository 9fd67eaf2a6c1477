"""RerunSink fed with real Simulator outputs: .rrd files checked with the `rerun` CLI and read back.

Oracles: the simulator's own outputs (the series must equal them), the lead relation
x_nut = (L/2π) θ_S and the gear relation ω_r = −g ω_C (docs/model.md §2) for the scene poses, Jones
2016's viscous law f = −c N_T v_s (friction arrows oppose the slip, at the documented length),
and the fu2018 tooth-load sharing Σ_k ζ_T,k = N_T (docs/model.md §4.2: tooth loads sum to the roller's
normal force).
"""

from __future__ import annotations

import math
import os
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from prsm_sim import OUTPUT_FIELDS, Simulator, preset
from prsm_sim.physics.contact import contact_for

from test_rerun_support import RERUN_BIN, entities, has_blueprint, rrd_component, rrd_rows, rrd_verify
from test_rerun_support import strict_rerun  # noqa: F401  (fixture, used by pytestmark)

import rerun as rr  # noqa: F401  (the test extra installs it; a missing install must fail, not skip)
from prsm_ros.viz.scene import arrow_length_m  # noqa: E402
from prsm_ros.viz.sink import RerunSink  # noqa: E402
from prsm_ros.viz.series import block_path, scalar_path  # noqa: E402

N_STEPS = 1500
RATE_HZ = 30.0


pytestmark = pytest.mark.usefixtures("strict_rerun")


def run_into(sink: RerunSink, model: str, n: int = N_STEPS, preset_name: str = "s30"):
    """Step a simulator like the node does (one submit per step), torque reversed halfway."""
    params = preset(preset_name)
    sim = Simulator(params, model, dt_s=1e-3)
    outs = []
    for k in range(n):
        out = sim.step(3.0 if k < n // 2 else -3.0, 2000.0)
        sink.submit(out)
        outs.append(out)
    sink.close()
    return params, sim, outs


def expected_frames(outs, rate_hz: float = RATE_HZ) -> int:
    """Scene frames at `rate_hz`: one per distinct 1/rate_hz slot of step times (integer ms arithmetic)."""
    return len({round(o.time_s * 1000) * int(rate_hz) // 1000 for o in outs})


@pytest.fixture(scope="module")
def jones_run(tmp_path_factory):
    path = tmp_path_factory.mktemp("rr") / "jones.rrd"
    params = preset("s30")
    sink = RerunSink("save", str(path), params, Simulator(params, "jones2016").layout, "jones2016",
                     scene_rate_hz=RATE_HZ)
    params, sim, outs = run_into(sink, "jones2016")
    return path, params, sim, outs, sink


def test_save_mode_file_verifies_and_holds_every_step(jones_run):
    path, params, sim, outs, sink = jones_run
    res = rrd_verify(path)
    assert res.returncode == 0, res.stderr
    assert "verified without error" in res.stdout + res.stderr
    rows = rrd_rows(path)
    for name, _ in OUTPUT_FIELDS[1:]:
        assert rows[(f"/{scalar_path(name)}", "Scalars:scalars")] == N_STEPS, name
    # the internal loads: the first step of each 1/120 s, every scene frame among them (120 = 4 × 30 Hz)
    assert sink.loads_rate_hz == 120.0
    for q, unit in sim.layout.blocks[0].quantities:
        assert rows[(f"/{block_path('per_roller', q, unit)}", "Scalars:scalars")] == expected_frames(outs, 120) == 181
    frames = expected_frames(outs)
    assert sink.stats()["scene_frames"] == frames == 46
    assert rows[("/world/screw", "Transform3D:quaternion")] == frames
    assert rows[("/world/nut", "Transform3D:translation")] == frames
    assert rows[("/world/nut/carrier", "Transform3D:quaternion")] == frames
    for q in range(params.geometry.n_rollers):
        assert rows[(f"/world/nut/carrier/roller_{q}", "Transform3D:translation")] == frames
    assert rows[("/world/nut/carrier/forces/screw_friction", "Arrows3D:vectors")] == frames
    assert rows[("/world/screw/thread", "LineStrips3D:strips")] == 1  # static geometry, logged once
    assert sink.stats()["dropped"] == 0 and sink.stats()["error"] is None
    # the default layout travels in the file
    assert has_blueprint(path)
    assert "/viewport" in entities(rows)


def test_series_equal_the_simulator_outputs(jones_run):
    path, _, _, outs, _ = jones_run
    for name, scale in (("nut_position_m", 1e3), ("screw_torque_nm", 1.0), ("speed_ratio", 1.0)):
        t_ns, vals = rrd_component(path, f"/{scalar_path(name)}", "Scalars:scalars")
        want = np.array([getattr(o, name) for o in outs]) * scale  # lengths in mm, as the report shows them
        np.testing.assert_array_equal(t_ns, [round(o.time_s * 1e9) for o in outs])
        np.testing.assert_allclose(np.array(vals).ravel(), want, rtol=0, atol=0, equal_nan=True)


def _z_angle(rows) -> np.ndarray:
    q = np.array(rows)[:, 0, :]  # one quaternion (xyzw) per row
    return 2 * np.arctan2(q[:, 2], q[:, 3])


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def test_scene_poses_follow_lead_and_gear(jones_run):
    """Nut at z = −x_nut = −(L/2π) θ_S; roller spin relative to the carrier −g θ_C (docs/model.md §2)."""
    path, params, _, outs, _ = jones_run
    geo = params.geometry
    by_time = {round(o.time_s * 1e9): o for o in outs}
    t, q_screw = rrd_component(path, "/world/screw", "Transform3D:quaternion")
    t_nut, tr_nut = rrd_component(path, "/world/nut", "Transform3D:translation")
    np.testing.assert_array_equal(t, t_nut)
    theta_s = np.array([by_time[k].screw_angle_rad for k in t.tolist()])
    theta_c = np.array([by_time[k].carrier_angle_rad for k in t.tolist()])
    z = np.array(tr_nut)[:, 0, 2]  # poses are stored as float32
    np.testing.assert_allclose(z, -geo.lead_per_rad_m * theta_s, rtol=1e-6, atol=1e-9)
    assert z[len(z) // 2] < z[0] - 1e-3  # positive screw rotation first: the nut went down (−z)
    np.testing.assert_allclose(_wrap(_z_angle(q_screw) - theta_s), 0, atol=1e-5)
    _, q_carrier = rrd_component(path, "/world/nut/carrier", "Transform3D:quaternion")
    _, q_roller = rrd_component(path, "/world/nut/carrier/roller_3", "Transform3D:quaternion")
    np.testing.assert_allclose(_wrap(_z_angle(q_carrier) - theta_c), 0, atol=1e-5)
    np.testing.assert_allclose(_wrap(_z_angle(q_roller) + geo.gear_ratio * theta_c), 0, atol=1e-4)


def test_friction_arrows_oppose_slip_at_the_documented_length(jones_run):
    """Jones 2016: the screw's friction on each roller is −c N_T v_s, identical for every roller."""
    path, params, _, _, _ = jones_run
    geo, c = params.geometry, params.friction.viscous_n_s_m
    nr = geo.n_rollers
    t_arrow, vectors = rrd_component(path, "/world/nut/carrier/forces/screw_friction", "Arrows3D:vectors")
    slip = {}
    for axis in ("radial", "tangential", "axial"):
        t, vals = rrd_component(path, f"/series/per_roller/screw_slip_{axis}_mm_s", "Scalars:scalars")
        slip[axis] = dict(zip(t.tolist(), (np.asarray(v) * 1e-3 for v in vals), strict=True))  # shown in mm/s
    checked = 0
    for t, vec in zip(t_arrow.tolist(), vectors, strict=True):
        v_s = np.array([slip[a][t][0] for a in ("radial", "tangential", "axial")])  # roller 0, carrier frame
        assert all(slip[a][t][q] == slip[a][t][0] for a in slip for q in range(nr))  # identical rollers
        f = c * geo.n_teeth * np.linalg.norm(v_s)
        vec = np.array(vec).reshape(nr, 3)
        for q in range(nr):
            phi = 2 * math.pi * q / nr
            rot = np.array([[math.cos(phi), -math.sin(phi), 0], [math.sin(phi), math.cos(phi), 0], [0, 0, 1]])
            length = np.linalg.norm(vec[q])
            assert length == pytest.approx(arrow_length_m(f, geo.roller_radius_m), rel=1e-5, abs=1e-9)
            if f > 1e-3:
                assert np.dot(vec[q] / length, rot @ v_s / np.linalg.norm(v_s)) == pytest.approx(-1.0, abs=1e-5)
                checked += 1
    assert checked > nr * 30


def test_fu2018_normal_arrows_tooth_points_and_heat_maps(tmp_path):
    """The real fu2018 layout: normal forces along the contact normals; tooth loads sum to the roller's."""
    path = tmp_path / "fu.rrd"
    params = preset("s30")
    sim = Simulator(params, "fu2018")
    sink = RerunSink("save", str(path), params, sim.layout, "fu2018", scene_rate_hz=RATE_HZ, loads_rate_hz=None)
    _, sim, outs = run_into(sink, "fu2018", n=600)
    assert rrd_verify(path).returncode == 0
    geo, nr, nt = params.geometry, params.geometry.n_rollers, params.geometry.n_teeth
    frames = expected_frames(outs)
    rows = rrd_rows(path)
    assert rows[("/series/per_roller/screw_normal_force_n", "Scalars:scalars")] == 600  # loads_rate_hz None: every step
    for fam in ("screw_normal_force", "nut_normal_force", "screw_friction", "gear_force", "pin_force"):
        assert rows[(f"/world/nut/carrier/forces/{fam}", "Arrows3D:vectors")] == frames, fam
    for side in ("screw", "nut"):
        assert rows[(f"/world/nut/carrier/tooth_loads/{side}_normal_force_n", "Points3D:positions")] == frames
        assert rows[(f"/loads/per_tooth/{side}_normal_force_n", "Tensor:data")] == frames
    by_time = {round(o.time_s * 1e9): o for o in outs}
    t_arrow, vectors = rrd_component(path, "/world/nut/carrier/forces/screw_normal_force", "Arrows3D:vectors")
    t_tensor, tensors = rrd_component(path, "/loads/per_tooth/screw_normal_force_n", "Tensor:data")
    np.testing.assert_array_equal(t_arrow, t_tensor)
    for t, vec, tensor in zip(t_arrow.tolist(), vectors, tensors, strict=True):
        out = by_time[t]
        per_roller = sim.layout.view(out.internal, "per_roller")
        sign = 1 if sim.layout.view(out.internal, "carrier")[2] >= 0 else -1
        normal = contact_for(geo, "screw", params.friction.contact_evaluation, sign).normal_on_roller
        vec = np.array(vec).reshape(nr, 3)
        n0 = per_roller[0, 0]
        assert np.linalg.norm(vec[0]) == pytest.approx(arrow_length_m(n0, geo.roller_radius_m), rel=1e-5)
        assert vec[0] / np.linalg.norm(vec[0]) == pytest.approx(normal, abs=1e-6)
        (data,) = tensor  # one tensor per row: {shape, names, buffer}
        assert data["shape"] == [nr, nt] and data["names"] == ["roller", "tooth"]
        loads = np.array(data["buffer"], dtype=float)
        loads = loads.reshape(nr, nt)
        np.testing.assert_allclose(loads.sum(axis=1), per_roller[:, 0], rtol=1e-9)


def test_full_queue_drops_and_counts(tmp_path):
    """The loop is never held up: past queue_size the steps are dropped and counted, the rest recorded."""
    path = tmp_path / "small.rrd"
    params = preset("jones2016")
    sink = RerunSink("save", str(path), params, Simulator(params, "jones2016").layout, "jones2016",
                     queue_size=10, flush_period_s=10.0)
    run_into(sink, "jones2016", n=50, preset_name="jones2016")
    assert sink.dropped == 40 and sink.submitted == 10
    assert rrd_verify(path).returncode == 0
    assert rrd_rows(path)[("/series/nut_position_mm", "Scalars:scalars")] == 10


def _fds_on(path) -> list[str]:
    """Open file descriptors of this process that point at `path` (deleted or not)."""
    out = []
    for fd in os.listdir("/proc/self/fd"):
        try:
            target = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            continue
        if target.startswith(str(path)):
            out.append(target)
    return out


def test_a_start_that_fails_after_save_leaves_no_stream_file_or_thread(tmp_path, monkeypatch):
    """A failure after `rec.save` opened the file (here: the static scene) must close the stream:
    no descriptor on the .rrd, no half-written file of a run that never happened, no thread."""
    import threading

    from prsm_ros.viz import sink as sink_module

    def boom(self):
        raise RuntimeError("static scene failed")

    monkeypatch.setattr(sink_module.RecordingWriter, "log_static", boom)
    path = tmp_path / "failed.rrd"
    params = preset("jones2016")
    with pytest.raises(RuntimeError, match="static scene failed"):
        RerunSink("save", str(path), params, Simulator(params, "jones2016").layout, "jones2016")
    assert not path.exists() and _fds_on(path) == []
    assert "prsm-rerun-sink" not in [t.name for t in threading.enumerate()]


def test_close_is_bounded_when_the_background_thread_hangs(tmp_path, monkeypatch):
    """The background thread is stuck in a send (a stalled viewer connection): close() returns
    after its timeout with the error said and the steps it could not send counted in `lost`,
    and the stream is still closed (no descriptor left on the .rrd)."""
    import threading

    from prsm_ros.viz import sink as sink_module

    release, blocked = threading.Event(), threading.Event()
    real_send = sink_module.RecordingWriter.send

    def stuck_send(self, columns, internal, **parts):
        blocked.set()
        release.wait(30)
        real_send(self, columns, internal, **parts)

    monkeypatch.setattr(sink_module.RecordingWriter, "send", stuck_send)
    path = tmp_path / "stuck.rrd"
    params = preset("jones2016")
    sim = Simulator(params, "jones2016")
    sink = RerunSink("save", str(path), params, sim.layout, "jones2016", flush_period_s=0.01)
    sink.submit(sim.step(0.1, 10.0))
    assert blocked.wait(10)
    for _ in range(20):  # queued behind the stuck send
        sink.submit(sim.step(0.1, 10.0))
    t0 = time.monotonic()
    assert sink.close(timeout_s=0.5) is False
    assert time.monotonic() - t0 < 0.5 + 10.0  # the ceiling only absorbs a busy machine
    assert "did not finish within 0.5 s" in sink.error and sink.lost == 20 and sink.stats()["lost"] == 20
    assert _fds_on(path) == []
    release.set()
    sink._thread.join(10)
    assert not sink._thread.is_alive()


def test_a_script_that_never_closes_still_leaves_a_finished_file(tmp_path):
    path = tmp_path / "unclosed.rrd"
    code = ("from prsm_sim import Simulator, preset\n"
            "from prsm_ros.viz.sink import RerunSink\n"
            "p = preset('jones2016'); sim = Simulator(p, 'jones2016')\n"
            f"s = RerunSink('save', {str(path)!r}, p, sim.layout, 'jones2016')\n"
            "for _ in range(300): s.submit(sim.step(0.1, 10.0))\n")
    env = {k: v for k, v in os.environ.items() if k != "RERUN"}
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, env=env)
    assert res.returncode == 0, res.stderr
    assert rrd_verify(path).returncode == 0
    assert rrd_rows(path)[("/series/nut_position_mm", "Scalars:scalars")] == 300


def test_off_mode_starts_and_imports_nothing():
    code = ("import sys\n"
            "from prsm_sim import Simulator, preset\n"
            "from prsm_ros.viz.sink import RerunSink\n"
            "p = preset('jones2016'); sim = Simulator(p, 'jones2016')\n"
            "s = RerunSink('off', 'ignored.rrd', p, sim.layout, 'jones2016')\n"
            "s.submit(sim.step(0.1, 10.0)); s.close()\n"
            "print('rerun' in sys.modules, s.writer is None, s.stats()['submitted'])\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert res.stdout.split() == ["False", "True", "0"]


def test_environment_rerun_off_forces_off(tmp_path, monkeypatch):
    monkeypatch.setenv("RERUN", "off")
    path = tmp_path / "never.rrd"
    params = preset("jones2016")
    sink = RerunSink("save", str(path), params, Simulator(params, "jones2016").layout, "jones2016")
    assert sink.mode == "off" and sink.requested_mode == "save"
    run_into(sink, "jones2016", n=20, preset_name="jones2016")
    assert not path.exists()


@pytest.mark.parametrize("mode,target,words", [
    ("file", "x.rrd", ["rerun = 'file'", "off, save, spawn, connect"]),
    ("save", "/nonexistent_dir_for_prsm/x.rrd", ["does not exist"]),
    ("save", "{tmp}", ["is a directory"]),
    ("connect", "http://localhost:9876", ["rerun+http://HOST:PORT/proxy"]),
    ("connect", "localhost:99999", ["port 1-65535"]),
    ("spawn", "viewer", ["port (1-65535)"]),
])
def test_bad_mode_or_target_is_one_clear_error(tmp_path, mode, target, words):
    params = preset("jones2016")
    layout = Simulator(params, "jones2016").layout
    with pytest.raises(ValueError) as err:
        RerunSink(mode, target.format(tmp=tmp_path), params, layout, "jones2016")
    for w in words:
        assert w in str(err.value)
    assert list(tmp_path.iterdir()) == []


def test_bad_scene_rate_is_refused(tmp_path):
    params = preset("jones2016")
    with pytest.raises(ValueError, match="scene_rate_hz"):
        RerunSink("save", str(tmp_path / "x.rrd"), params, Simulator(params, "jones2016").layout, "jones2016",
                  scene_rate_hz=0.0)


def test_loads_samples_hold_every_scene_frame_and_do_not_depend_on_where_batches_are_cut():
    """The first step of each 1/rate slot (integer ms arithmetic as the oracle), every scene frame among
    them even at a rate that is no multiple of the scene's, and the same rows whatever the batches."""
    from prsm_ros.viz.scene import scene_frame_indices
    from prsm_ros.viz.sink import loads_sample_rows

    t = np.arange(1, 2001) * 1e-3
    whole, _ = loads_sample_rows(t, 100.0, 30.0, (-1, -1))
    ms = np.arange(1, 2001)
    firsts = {int(np.flatnonzero(ms * r // 1000 == slot)[0]) for r in (100, 30) for slot in set(ms * r // 1000)}
    assert whole.tolist() == sorted(firsts)
    frames, _ = scene_frame_indices(t, 30.0, -1)
    assert set(frames.tolist()) <= set(whole.tolist())
    rng = np.random.default_rng(7)
    cuts = np.sort(rng.choice(np.arange(1, 2000), 25, replace=False))
    slots, parts = (-1, -1), []
    for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, 2000], strict=True):
        idx, slots = loads_sample_rows(t[lo:hi], 100.0, 30.0, slots)
        parts.extend((idx + lo).tolist())
    assert parts == whole.tolist()
    every, same = loads_sample_rows(t[:10], None, 30.0, (3, 4))
    assert every.tolist() == list(range(10)) and same == (3, 4)


@pytest.mark.parametrize("rate", [0.0, -1.0, math.inf, math.nan, "120"])
def test_bad_loads_rate_is_refused_before_anything_starts(tmp_path, rate):
    params = preset("jones2016")
    with pytest.raises(ValueError, match="loads_rate_hz"):
        RerunSink("save", str(tmp_path / "x.rrd"), params, Simulator(params, "jones2016").layout, "jones2016",
                  loads_rate_hz=rate)
    assert list(tmp_path.iterdir()) == []


# -- streaming modes: a real gRPC server (the rerun binary) receives the data ------------------------

def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_port(port: int, timeout_s: float = 20.0) -> None:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.1)
    raise TimeoutError(f"nothing listening on port {port} after {timeout_s} s")


def _wait_display(display: str, server: subprocess.Popen, timeout_s: float = 60.0) -> None:
    """Until the X server of `display` (":N") listens on its socket, /tmp/.X11-unix/XN."""
    sock = os.path.join("/tmp/.X11-unix", f"X{display.lstrip(':')}")
    end = time.monotonic() + timeout_s
    while not os.path.exists(sock):
        if server.poll() is not None or time.monotonic() > end:
            raise TimeoutError(f"no X server on {display} after {timeout_s} s (exit status {server.poll()})")
        time.sleep(0.05)


def _stop(proc: subprocess.Popen) -> None:
    proc.terminate()
    try:
        proc.wait(timeout=2)
    except subprocess.TimeoutExpired:  # the server ignores SIGTERM while clients are connected
        proc.kill()
        proc.wait(timeout=5)


def _received(port: int, path) -> dict:
    """What a server on `port` holds: a late client saves its buffered stream to `path`."""
    client = subprocess.Popen([str(RERUN_BIN), "--connect", f"rerun+http://127.0.0.1:{port}/proxy", "--save",
                               str(path)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        end = time.monotonic() + 20
        rows = {}
        while time.monotonic() < end:
            time.sleep(0.5)
            rows = rrd_rows(path) if path.exists() else {}
            if rows.get(("/series/nut_position_mm", "Scalars:scalars"), 0) >= 300:
                break
        return rows
    finally:
        _stop(client)


@pytest.fixture
def grpc_server(tmp_path):
    port = _free_port()
    proc = subprocess.Popen([str(RERUN_BIN), "--serve-grpc", "--port", str(port)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        _wait_port(port)
        yield port
    finally:
        _stop(proc)


@pytest.mark.parametrize("target", ["{port}", "127.0.0.1:{port}", "rerun+http://127.0.0.1:{port}/proxy"])
def test_connect_mode_streams_every_step_to_a_server(grpc_server, tmp_path, target):
    params = preset("jones2016")
    sink = RerunSink("connect", target.format(port=grpc_server), params, Simulator(params, "jones2016").layout,
                     "jones2016")
    assert sink.url == f"rerun+http://127.0.0.1:{grpc_server}/proxy"
    run_into(sink, "jones2016", n=300, preset_name="jones2016")
    assert sink.error is None
    rows = _received(grpc_server, tmp_path / "received.rrd")
    assert rows[("/series/nut_position_mm", "Scalars:scalars")] == 300
    assert rows[("/world/nut", "Transform3D:translation")] == 10
    assert "/viewport" in entities(rows)  # the blueprint went along


def test_spawn_mode_uses_a_viewer_already_on_the_port(grpc_server, tmp_path):
    """spawn with a viewer (here a server) already listening connects to it instead of starting another."""
    params = preset("jones2016")
    sink = RerunSink("spawn", str(grpc_server), params, Simulator(params, "jones2016").layout, "jones2016")
    run_into(sink, "jones2016", n=300, preset_name="jones2016")
    assert sink.error is None
    assert _received(grpc_server, tmp_path / "received.rrd")[("/series/nut_position_mm", "Scalars:scalars")] == 300


def _listener_pid(port: int) -> int | None:
    out = subprocess.run(["ss", "-ltnpH", f"sport = :{port}"], capture_output=True, text=True).stdout
    for part in out.split("pid=")[1:]:
        return int(part.split(",")[0])
    return None


@pytest.mark.skipif(not os.path.exists("/usr/bin/Xvfb"), reason="needs Xvfb to run the native viewer")
def test_spawn_mode_starts_a_native_viewer(tmp_path, monkeypatch):
    display = f":{150 + os.getpid() % 100}"
    xvfb = subprocess.Popen(["/usr/bin/Xvfb", display, "-screen", "0", "1280x800x24"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    port = _free_port()
    viewer = None
    try:
        _wait_display(display, xvfb)
        monkeypatch.setenv("DISPLAY", display)
        monkeypatch.setenv("PATH", f"{RERUN_BIN.parent}{os.pathsep}{os.environ['PATH']}")
        params = preset("jones2016")
        sink = RerunSink("spawn", str(port), params, Simulator(params, "jones2016").layout, "jones2016")
        _wait_port(port)
        viewer = _listener_pid(port)
        run_into(sink, "jones2016", n=300, preset_name="jones2016")
        assert sink.error is None and viewer is not None
        assert _received(port, tmp_path / "received.rrd")[("/series/nut_position_mm", "Scalars:scalars")] == 300
    finally:
        if viewer is not None:
            os.kill(viewer, 9)
        xvfb.terminate()
        xvfb.wait(timeout=10)
