"""The node's pure pieces without DDS: command gate, deadline pacer, stepper, message mapping, parameters."""

from __future__ import annotations

import math

import numpy as np
import pytest

from prsm_sim import MODELS, OUTPUT_FIELDS, ModelError, Session, Simulator, preset
from prsm_sim.command_gate import CommandGate
from prsm_ros.node.joint_commands import offer_joint_command
from prsm_ros.node.parameters import ConfigError, NodeConfig, runtime_change
from prsm_ros.node.pacing import DeadlinePacer, every_n_steps


def test_gate_rejects_non_finite_keeps_last_and_saturates():
    g = CommandGate(max_effort_nm=2.0)
    assert g.torque(0.0) == 0.0  # nothing received yet
    assert g.offer_torque(1.5, 0.0) is None and g.torque(0.001) == 1.5
    for bad in (math.nan, math.inf, -math.inf, "x"):
        assert "not a finite number" in g.offer_torque(bad, 0.001)
    assert g.torque(0.002) == 1.5
    assert g.offer_torque(3.0, 0.002) is None and g.torque(0.002) == 2.0
    assert g.offer_torque(-9.0, 0.002) is None and g.torque(0.002) == -2.0
    c = g.counters
    assert (c.received, c.accepted, c.rejected_non_finite, c.saturated) == (7, 3, 4, 2)


@pytest.mark.parametrize("names, effort, position, velocity, problem", [
    (["a"], [1.0], [], [], "has no 'screw_joint'"),
    (["screw_joint", "b", "c"], [1.0, 2.0], [], [], "3 names but 2 effort values"),
    (["screw_joint"], [], [], [], "no effort value"),
    (["screw_joint", "nut_joint"], [], [0.1], [], "the active command interface is 'effort'"),
])
def test_gate_rejects_malformed_joint_commands_by_name(names, effort, position, velocity, problem):
    s = Session(preset("s30"), "ideal", 1e-3, max_effort_nm=5.0)
    s.offer("effort", 1.0)
    assert problem in offer_joint_command(s, names, {"effort": effort, "position": position, "velocity": velocity})
    assert s.gate.torque(0.0) == 1.0 and s.gate.counters.rejected_malformed == 1
    arrays = {"effort": [7.0, -0.5], "position": [0.0, 0.0], "velocity": []}
    assert offer_joint_command(s, ["b", "screw_joint"], arrays) is None
    assert s.gate.torque(0.0) == -0.5


@pytest.mark.parametrize("behaviour, after", [("zero", 0.0), ("hold", 1.0)])
def test_gate_watchdog_on_simulation_time(behaviour, after):
    g = CommandGate(5.0, cmd_timeout_s=0.01, timeout_behaviour=behaviour)
    g.offer_torque(1.0, 0.1)
    assert g.torque(0.11) == 1.0 and not g.timed_out  # exactly cmd_timeout old: still valid
    assert g.torque(0.1101) == after and g.timed_out
    g.torque(0.2)
    assert g.counters.timeouts == 1  # one entry into the timed-out state, however long it lasts
    g.offer_torque(0.5, 0.3)
    assert g.torque(0.3) == 0.5 and not g.timed_out
    g.configure(5.0, 0.0, behaviour)  # 0 disables
    assert g.torque(100.0) == 0.5


def test_gate_refuses_bad_limits():
    with pytest.raises(ValueError, match="max_effort"):
        CommandGate(0.0)
    with pytest.raises(ValueError, match="timeout_behaviour"):
        CommandGate(1.0, 0.1, "coast")


class FakeTime:
    """A wall clock the test moves: sleep advances it by the request plus a scripted delay."""

    def __init__(self):
        self.now, self.extra = 0.0, []

    def clock(self):
        return self.now

    def sleep(self, dt):
        self.now += dt + (self.extra.pop(0) if self.extra else 0.0)


def test_pacer_absolute_deadlines_do_not_drift_after_a_late_step():
    ft = FakeTime()
    p = DeadlinePacer(1e-3, clock=ft.clock, sleep=ft.sleep)
    ft.extra = [0.0, 0.0025]  # the second wake-up comes 2.5 ms late
    late = [p.wait() for _ in range(6)]
    assert late[0] == 0.0 and late[1] == pytest.approx(0.0025)
    # the late step is followed by catch-up steps without sleeping, then the original schedule
    assert late[2] == pytest.approx(0.0015) and late[3] == pytest.approx(0.0005) and late[4] == 0.0
    assert ft.now == pytest.approx(0.006) and p.stats.overruns == 2  # started > 1 period late: 2.5, 1.5 ms
    for _ in range(994):
        p.wait()
    assert ft.now == pytest.approx(1.0, abs=1e-12)  # 1000 steps end exactly at 1 s: no drift
    assert p.achieved_rtf(1e-3) == pytest.approx(1.0)


def test_pacer_skips_ahead_when_too_far_behind_and_follows_the_real_time_factor():
    ft = FakeTime()
    p = DeadlinePacer(1e-3, real_time_factor=2.0, max_catchup_periods=10, clock=ft.clock, sleep=ft.sleep)
    assert p.period_s == 5e-4
    ft.extra = [0.1]  # 200 periods late
    p.wait()
    assert p.stats.skipped_periods == 200
    before = ft.now
    p.wait()
    assert ft.now - before == pytest.approx(5e-4)  # back on a schedule, no burst of 200 steps


def test_pacer_restarted_during_a_sleep_waits_on_the_new_schedule():
    """The executor thread restarts the pacer (a reset, a new rate) while the step thread sleeps
    towards the old deadline: the step must come one period after the restart, not at the stale
    deadline, and the figures start again from that restart."""
    ft = FakeTime()
    p = DeadlinePacer(1e-3, clock=ft.clock, sleep=lambda dt: sleep(dt))
    restart_now = False

    def sleep(dt):
        nonlocal restart_now
        if restart_now:  # halfway through this sleep, another thread restarts the schedule
            restart_now = False
            ft.now += dt / 2
            p.restart()
            ft.now += dt / 2
        else:
            ft.now += dt

    p.wait(), p.wait()
    assert ft.now == pytest.approx(2e-3)
    restart_now = True
    assert p.wait() == 0.0
    assert ft.now == pytest.approx(3.5e-3) and p.snapshot().steps == 1  # restart at 2.5 ms + one period
    p.set_rate(2.0)  # a rate change restarts too: next step one new period (0.5 ms) later
    p.wait()
    assert ft.now == pytest.approx(4e-3) and p.snapshot().steps == 1
    assert p.count_step() == 2 and p.snapshot().overruns == 0


def test_node_close_is_bounded_when_the_step_thread_hangs(tmp_path, monkeypatch):
    """PrsmNode.close with a step thread stuck inside a step: close returns after the step
    thread's timeout, says so, still finishes the MCAP file, and the step's late write is counted
    as dropped instead of landing in a finished file (or hanging shutdown)."""
    import threading

    from std_msgs.msg import Float64

    from prsm_ros.mcap.recorder import McapRecorder
    from prsm_ros.messages import TOPICS
    from prsm_ros.bag.reader import open_bag
    import prsm_ros.node.ros_node as ros_node
    from prsm_ros.node.sinks import RecorderSink, Sinks

    monkeypatch.setattr(ros_node, "STEP_THREAD_STOP_S", 0.2)
    rec = McapRecorder(tmp_path / "node.mcap")
    rec.add_channel("/clock_like", Float64, TOPICS["screw_torque"].qos)
    rec.write("/clock_like", Float64(data=1.0), 1)
    release, in_step = threading.Event(), threading.Event()

    def stuck_step():
        in_step.set()
        release.wait(30)  # a model step that outlives the stop timeout
        rec.write("/clock_like", Float64(data=2.0), 2)

    class Node:  # what PrsmNode.close touches
        close = ros_node.PrsmNode.close

        def __init__(self):
            self._stop, self._resumed = threading.Event(), threading.Event()
            self.errors = []
            self.sinks = Sinks([RecorderSink(rec)])
            self._thread = threading.Thread(target=stuck_step, daemon=True)
            self._thread.start()

        def get_logger(self):
            return self

        def error(self, text):
            self.errors.append(text)

    node = Node()
    assert in_step.wait(10)
    node.close()
    assert node._stop.is_set() and node._thread.is_alive()
    assert any("did not stop within 0.2 s" in e for e in node.errors), node.errors
    assert rec.error is None and rec.messages_written == 1
    release.set()
    node._thread.join(10)
    assert rec.messages_written == 1 and rec.messages_dropped == 1
    bag = open_bag(tmp_path / "node.mcap")
    assert bag.complete and bag.topics["/clock_like"].count == 1


def test_every_n_steps():
    assert [every_n_steps(r, 1000) for r in (0, 1000, 5000, 100, 300, 0.5)] == [1, 1, 1, 10, 3, 2000]


def test_session_equals_simulator_and_rebuild_keeps_state():
    p = preset("s30")
    st = Session(p, "jones2016", 1e-3, load_n=100.0, max_effort_nm=10.0)
    st.offer("effort", 1.0)
    sim = Simulator(p, "jones2016", 1e-3)
    for _ in range(5):
        a, b = st.step(), sim.step(1.0, 100.0)
        np.testing.assert_array_equal(list(a.scalars().values()), list(b.scalars().values()))  # NaN == NaN here
        np.testing.assert_array_equal(a.internal, b.internal)
    assert st.simulator.state == sim.state
    p2 = p.with_overrides({"friction.viscous_n_s_m": 50.0})
    st.rebuild(p2)
    assert st.simulator.state == sim.state and st.nstep == 5 and st.simulator.params == p2


def test_session_faults_on_non_finite_state_and_reset_clears_it():
    p = preset("s30").with_overrides({"mass.moved_mass_kg": 1e-300, "mass.screw_inertia_kgm2": 0.0,
                                      "mass.roller_mass_kg": 0.0, "mass.roller_inertia_kgm2": 0.0})
    st = Session(p, "fu2018", 1e-3, max_effort_nm=10.0)
    with pytest.raises(ModelError, match="non-finite state"):
        st.step(1.0)
    assert "non-finite state" in st.fault
    assert st.nstep == 0 and st.time_s == 0.0  # the last finite state is kept
    with pytest.raises(ModelError, match="non-finite state"):  # stays stopped
        st.step()
    st.reset()
    assert st.fault is None and st.gate.command_nm == 0.0


@pytest.mark.parametrize("model", sorted(MODELS))
def test_internal_loads_message_round_trips_through_the_labels(model):
    from prsm_ros.messages import MessageMapper, parse_labels, unpack_internal
    sim = Simulator(preset("s30"), model, 1e-3)
    outs = [sim.step(2.0, 100.0) for _ in range(3)]
    mapper = MessageMapper(sim.layout, model)
    labels = parse_labels(mapper.labels().data)
    assert labels["model"] == model and labels["layout_obj"] == sim.layout
    assert len(labels["elements"]) == mapper.size == len(OUTPUT_FIELDS) + sim.layout.size
    msg = mapper.internal_loads(outs[-1])
    assert [d.label for d in msg.layout.dim] == ["scalars"] + [b.name for b in sim.layout.blocks]
    one = unpack_internal(msg, labels)
    assert one["nut_force_n"] == outs[-1].nut_force_n and one["time_s"] == outs[-1].time_s
    for b in sim.layout.blocks:
        np.testing.assert_array_equal(one[b.name], sim.layout.view(outs[-1].internal, b.name))
    rows = np.array([mapper.internal_loads(o).data for o in outs])
    many = unpack_internal(rows, labels)
    assert many["time_s"].tolist() == [o.time_s for o in outs]
    topics = [t for t, _ in mapper.messages(outs[0])]
    assert topics == ["/joint_states", "/prsm_actuator/nut/wrench", "/prsm_actuator/internal_loads", "/clock"]


def test_config_defaults_and_runtime_change_rules():
    cfg = NodeConfig.from_values({})
    assert cfg.params == preset("s30") and cfg.dt_s == 1e-3 and cfg.time_mode == "realtime"
    new = runtime_change(cfg, {"load_force": 10, "physics.friction.mu_screw_roller": 0.2})
    assert new.load_force == 10.0 and isinstance(new.load_force, float)
    assert new.params.friction.mu_screw_roller == 0.2 and cfg.params.friction.mu_screw_roller == 0.05
    with pytest.raises(ConfigError, match="changes the internal-load layout"):
        runtime_change(cfg, {"physics.geometry.n_rollers": 8})
    with pytest.raises(ConfigError, match=r"parameter lockstep_steps = 0: must be a whole number in \[1"):
        runtime_change(cfg, {"lockstep_steps": 0})


def test_simulation_report_levels_from_the_session_status():
    """The /diagnostics rules without DDS: ERROR for a stopped session or an open energy ledger,
    WARN for an active actuator fault or a watchdog timeout, else OK with the run state."""
    from prsm_sim.actuator import ActuatorParams, Fault, MotorParams
    from prsm_ros.node.diagnostics import ERROR, OK, WARN, energy_fault_event, simulation_report

    s = Session(preset("s30"), "ideal", 1e-3, ActuatorParams(motor=MotorParams()), cmd_timeout_s=0.002)
    r = simulation_report(s.status(), {"time_mode": "lockstep"}, [], [])
    assert (r.level, r.message) == (OK, "running") and r.values["commands_received"] == 0
    assert r.values["time_mode"] == "lockstep" and r.values["command_age_s"] == "none yet"
    s.step(1.0)
    s.inject(Fault("jam", start_s=s.time_s, value=0.5))
    s.step()
    r = simulation_report(s.status(), {}, ["recorder: disk full"], ["t = 0.001 s: fault start: jam"])
    assert r.level == WARN and r.message.startswith("fault(s) active: ") and "recorder: disk full" in r.message
    assert r.values["fault_events"] == "t = 0.001 s: fault start: jam"
    for _ in range(3):
        s.step()
    assert "no command for" in simulation_report(s.status(), {}, [], []).message  # the watchdog
    s.fail("publishing step 5 failed")
    assert simulation_report(s.status(), {}, [], [])[:2] == (ERROR, "publishing step 5 failed")
    text, details = energy_fault_event(0.5, 10.0, 0.02, "ideal")
    assert "residual 0.02 J of 10 J that flowed (limit 0.001)" in text and details["flow_j"] == 10.0


class _VolatilePub:
    """A volatile publisher with `readers` matched readers, as `Outlets` uses one; what it sends is kept."""

    def __init__(self, readers):
        from rclpy.qos import QoSProfile
        self.readers, self.sent, self.qos_profile, self.handle = readers, [], QoSProfile(depth=10), self

    def get_subscription_count(self):
        return self.readers

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def publish_raw(self, data):
        self.sent.append(data)


def test_internal_loads_go_to_dds_and_live_views_at_their_rate_and_to_the_bag_at_its_own():
    """`Outlets.publish_loads` and `Sinks.write_step`, without DDS: over 40 steps at 1 kHz, DDS and a live view
    get the internal loads at `internal_loads_rate` (100 Hz: steps 10, 20, 30, 40), the bag at
    `record_internal_loads_rate` (250 Hz: every 4th step), and every other message of a step goes to both; where
    the bag alone gets them it gets them unbuilt (`Deferred`), which build to the encoder's bytes.
    Oracle: the rates' own arithmetic (steps k with k mod n = 0)."""
    from types import SimpleNamespace


    from prsm_ros.mcap.recorder import Deferred
    from prsm_ros.messages import MessageMapper, time_ns
    from prsm_ros.node.outlets import Outlets
    from prsm_ros.node.sinks import FoxgloveSink, RecorderSink, Sinks

    class MessageSink:  # the bag (keeps_record) or a live view; what it is handed is kept, per step
        takes_messages, takes_outputs, error = True, False, None

        def __init__(self, keeps_record):
            self.keeps_record, self.steps, self.deferred = keeps_record, [], []

        def write_many(self, items):
            self.steps.append([topic for topic, _, _ in items])
            self.deferred += [m for _, m, _ in items if type(m) is Deferred]

    session = Session(preset("s30"), "fu2018", 1e-3)
    cfg = SimpleNamespace(joint_states_rate=0.0, update_rate=1000.0, time_mode="realtime", internal_loads_rate=100.0,
                          record_internal_loads_rate=250.0)
    names = {"internal_loads": "/il", "clock": "/clock"}
    for readers, live in ((1, True), (0, False)):
        pubs = {k: _VolatilePub(readers) for k in names}
        bag, view = MessageSink(True), MessageSink(False)
        mapper = MessageMapper(session.layout, "fu2018")
        node = SimpleNamespace(session=session, mapper=mapper, config=cfg)
        outlets = Outlets(node, pubs, names, Sinks([bag, view] if live else [bag]), frozenset(), warn=None)
        built = []
        encode = outlets.encoder.internal_loads
        outlets.encoder = SimpleNamespace(internal_loads=lambda out: built.append(out) or encode(out))
        outlets.count_readers()
        for k in range(1, 41):
            out = session.step()
            outlets.begin_step()
            outlets.publish("clock", b"\0" * 8, time_ns(out.time_s))
            outlets.publish_loads(out, k, time_ns(out.time_s))
            outlets.end_step()
        every = {n: [k for k in range(1, 41) if k % n == 0] for n in (4, 10)}
        assert [k for k, s in enumerate(bag.steps, 1) if "/il" in s] == every[4]
        assert all(s[0] == "/clock" for s in bag.steps) and len(bag.steps) == 40
        assert len(pubs["internal_loads"].sent) == (len(every[10]) if readers else 0)
        assert len(pubs["clock"].sent) == (40 if readers else 0)
        if live:
            assert [k for k, s in enumerate(view.steps, 1) if "/il" in s] == every[10]
            assert all(s[0] == "/clock" for s in view.steps) and len(view.steps) == 40
        # the bytes are built only for a step someone gets them at: on the step thread where DDS or a live view
        # gets them, by the recorder (a `Deferred`, built here as its thread would) where the bag alone does
        now = set(every[10]) if readers or live else set()
        assert len(built) == len(now) and not view.deferred
        assert len(bag.deferred) == len(set(every[4]) - now)
        assert [d.build() for d in bag.deferred] == [encode(out) for out in built[len(now):]]
        assert len(built) == len(set(every[4]) | now)
    # the node's own sinks: the bag is the record, the Foxglove server a live view
    assert RecorderSink.keeps_record and not FoxgloveSink.keeps_record


def test_a_message_only_the_bag_gets_is_built_by_the_recorder_in_realtime_and_at_once_otherwise():
    """`Outlets.publish_built` on the wrench: where DDS has a reader, a live view takes messages or the node is not
    in realtime, the bytes are built on the step thread, sent and recorded; in realtime with none of those the bag
    gets a `Deferred` and DDS nothing. Oracle: the encoder's own bytes for the same step, and the rules above.
    Bytes are compared with their alignment padding zeroed: rclpy's serializer leaves it as it finds it in
    memory, so two encodings of one message can differ there (`CdrNormaliser`)."""
    from types import SimpleNamespace

    from prsm_ros.mcap.codec import CdrNormaliser
    from prsm_ros.mcap.recorder import Deferred
    from prsm_ros.messages import MessageMapper, time_ns
    from prsm_ros.node.outlets import Outlets
    from prsm_ros.node.sinks import Sinks

    class MessageSink:  # the bag (keeps_record) or a live view: what it is handed is kept
        takes_messages, takes_outputs, error = True, False, None

        def __init__(self, keeps_record):
            self.keeps_record, self.items = keeps_record, []

        def write_many(self, items):
            self.items += items

    session = Session(preset("s30"), "jones2016", 1e-3)
    out = session.step()
    ns = time_ns(out.time_s)
    mapper = MessageMapper(session.layout, "jones2016")
    normaliser = CdrNormaliser()

    def zeroed(data):
        return normaliser("geometry_msgs/msg/WrenchStamped", data)
    expected = zeroed(mapper.encoder().wrench(out, ns))
    for mode, readers, live, deferred in (("realtime", 0, False, True), ("realtime", 1, False, False),
                                          ("realtime", 0, True, False), ("fast", 0, False, False),
                                          ("lockstep", 0, False, False)):
        cfg = SimpleNamespace(joint_states_rate=0.0, update_rate=1000.0, time_mode=mode, internal_loads_rate=100.0,
                              record_internal_loads_rate=0.0)
        pubs = {"wrench": _VolatilePub(readers)}
        bag, view = MessageSink(True), MessageSink(False)
        node = SimpleNamespace(session=session, mapper=mapper, config=cfg)
        outlets = Outlets(node, pubs, {"wrench": "/wrench"}, Sinks([bag, view] if live else [bag]), frozenset(),
                          warn=None)
        outlets.count_readers()
        outlets.begin_step()
        outlets.publish_built("wrench", ns, outlets.encoder.wrench, out, ns)
        outlets.end_step()
        (topic, data, stamp), = bag.items
        assert (topic, stamp) == ("/wrench", ns)
        assert (type(data) is Deferred) == deferred, (mode, readers, live)
        assert zeroed(data.build() if deferred else data) == expected
        assert [zeroed(d) for d in pubs["wrench"].sent] == ([expected] if readers else [])
        assert [(t, zeroed(d), s) for t, d, s in view.items] == ([("/wrench", expected, ns)] if live else [])
