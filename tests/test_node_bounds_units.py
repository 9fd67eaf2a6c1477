"""The node's bounds and start-up checks as plain Python (no DDS): what grows is capped, what is
malformed is refused in one line.

Oracles: the stated caps (`ownership.REFUSED_LISTED`, `step_jobs.LOCKSTEP_BACKLOG_STEPS`), the s30
preset's thread travel ((0.3 − 0.03) m / 2 = 0.135 m), rcl's argument grammar.
"""

from __future__ import annotations

import threading

import pytest

from prsm_ros.node.locking import NodeLock
from prsm_ros.node.ownership import REFUSED_LISTED, CommandOwnership
from prsm_ros.node.parameters import ConfigError, NodeConfig, check_ros_args, node_parameters, runtime_change
from prsm_ros.node.step_jobs import LOCKSTEP_BACKLOG_STEPS, StepJobs


def _defaults() -> dict:
    return {p.name: p.default for p in node_parameters()}


def test_refused_participants_keep_counts_and_the_last_n():
    own = CommandOwnership(timeout_s=0.0)
    own.accepted(b"owner")
    writers = [bytes([i]) * 12 for i in range(1, 200)]
    for w in writers:
        assert own.admit(w) is not None
    c = own.counters
    assert c.refused == len(writers) and len(c.refused_by) == REFUSED_LISTED
    assert c.refused_unlisted == len(writers) - REFUSED_LISTED
    assert list(c.refused_by) == [w.hex() for w in writers[-REFUSED_LISTED:]]  # the most recent
    d = own.diagnostics()
    assert d["refused_participants_unlisted"] == len(writers) - REFUSED_LISTED
    assert own.admit(writers[0]) is not None and list(c.refused_by)[-1] == writers[0].hex()  # back at the end


def test_lockstep_backlog_refuses_beyond_its_cap():
    stop = threading.Event()
    release = threading.Event()

    def slow_slice(job, n):
        release.wait(10)
        return 0, "stopped"
    jobs = StepJobs(slow_slice, lambda job: None, stop)
    try:
        assert jobs.refuse_lockstep(1_000_000) is None
        jobs.submit(1_000_000, "lockstep command")
        assert jobs.refuse_lockstep(1_000_000) is None
        jobs.submit(1_000_000, "lockstep command")
        why = jobs.refuse_lockstep(1_000_000)
        assert why is not None and "lockstep backlog full" in why and f"{LOCKSTEP_BACKLOG_STEPS}" in why
        assert jobs.report()["lockstep_commands_refused_backlog"] == 1
        assert jobs.backlog()[1] <= LOCKSTEP_BACKLOG_STEPS
    finally:
        stop.set()
        release.set()
        jobs.stop()


@pytest.mark.parametrize("ros, words", [
    (["-p", "record_path:="], "no value after :="),
    (["-p"], "expected NAME:=VALUE after it"),
    (["-p", "a:=1", "-r"], "expected FROM:=TO after it"),
    (["--params-file", "-p", "a:=1"], "expected FILE after it"),
    (["-r", "__ns:=bad//ns"], "not a valid namespace"),
    (["-r", "__node:=a-b"], "not a valid node name"),
    (["-p", ":=1"], "expected NAME:=VALUE"),
])
def test_malformed_ros_arguments_are_named(ros, words):
    with pytest.raises(ConfigError, match=words):
        check_ros_args(["prsm-node", "--ros-args", *ros])


def test_well_formed_ros_arguments_pass():
    check_ros_args(["prsm-node", "--ros-args", "-p", "record:=false", "-r", "__ns:=/left", "-r", "__node:=act",
                    "--log-level", "info", "-p", "record_path:=''"])


def test_initial_nut_position_must_lie_on_the_threads_at_start_and_at_runtime():
    with pytest.raises(ConfigError, match=r"initial_nut_position = 1.0: must lie on the threads, \|x\| <= 0.135"):
        NodeConfig.from_values({**_defaults(), "initial_nut_position": 1.0})
    cfg = NodeConfig.from_values(_defaults())
    with pytest.raises(ConfigError, match="must lie on the threads"):
        runtime_change(cfg, {"initial_nut_position": 0.2})
    assert runtime_change(cfg, {"initial_nut_position": 0.1}).initial_nut_position == 0.1
    with pytest.raises(ConfigError, match="must lie on the threads"):  # a shorter screw moves the ends inwards
        runtime_change(runtime_change(cfg, {"initial_nut_position": 0.1}), {"physics.geometry.screw_length_m": 0.2})


def test_an_empty_parameter_name_is_refused():
    with pytest.raises(ConfigError, match="named ''"):
        runtime_change(NodeConfig.from_values(_defaults()), {"": 1.0})


def test_a_model_the_checks_pass_but_cannot_build_is_a_refusal():
    """A viscous coefficient of 1e300 N·s/m passes the parameter checks but leaves jones2016's
    discretisation non-finite: refused in one line naming it, never raised into the node."""
    cfg = NodeConfig.from_values(_defaults())
    with pytest.raises(ConfigError, match=r"physics.friction.viscous_n_s_m = 1e\+300: model jones2016 cannot be built"):
        runtime_change(cfg, {"physics.friction.viscous_n_s_m": 1e300})


def test_node_lock_lets_a_waiter_go_before_the_next_slice():
    lock = NodeLock()
    order = []
    entered = threading.Event()

    def waiter():
        entered.set()
        with lock:
            order.append("waiter")
    with lock:
        t = threading.Thread(target=waiter)
        t.start()
        entered.wait(10)
        while lock.waiting == 0:  # the waiter is blocked on the lock
            pass
    lock.let_waiters_first()
    with lock:
        order.append("slice")
    t.join(10)
    assert order == ["waiter", "slice"] and lock.waiting == 0


def test_ctl_reads_numbers_in_any_spelling_and_diagnostics_as_types(capsys):
    from prsm_ros.cli import ctl
    assert [ctl.parse_value(t) for t in ("-1e-1", "1_000", "+.5", "3", "true", "text")] == [-0.1, 1000, 0.5, 3, True,
                                                                                           "text"]
    assert [ctl.typed(t) for t in ("True", "False", "2.0", "12", "effort", "")] == [True, False, 2.0, 12, "effort", ""]
    with pytest.raises(SystemExit) as e:
        ctl.main(["--version"])
    assert e.value.code == 0 and capsys.readouterr().out.startswith("prsm-ctl ")
    args = ctl.build_parser().parse_args(["command", "torque", " -1e-1"])  # how main passes a negative number
    assert ctl._finite(args.value, "command torque") == -0.1
