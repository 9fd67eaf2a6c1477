"""The general events channel `~/events` (prsm_ros.messages.event_message): format, bag, report.

A recording made the node's way (McapRecorder, the node's channels) with a model whose energy
books do not close: the guard's event goes into the bag, an independent reader (rosbags) reads
it back, and `prsm-bag report` lists it.
"""

import json

import pytest

from prsm_sim import Params, preset
from prsm_sim.models.ideal import Ideal
from prsm_ros.cli.bag import main
from prsm_ros.messages import TOPICS, MessageMapper, STEP_TOPICS, event_message, time_ns
from prsm_ros.mcap.recorder import McapRecorder, run_metadata


class _Leaky(Ideal):
    """Books a third of its loss only: the energy guard must trip (a broken model stands in for a real fault)."""

    def _step_law(self):
        solve = super()._step_law()

        def leaky(w0, torque_nm, load_n):
            w1, dtheta, dissipated = solve(w0, torque_nm, load_n)
            return w1, dtheta, dissipated / 3.0
        return leaky


def test_event_message_is_one_json_object_and_refuses_unknown_severity():
    msg = event_message(1.25, "energy_guard", "error", "energy_balance", "books open", {"residual_j": -0.5})
    doc = json.loads(msg.data)
    assert doc == {"time_s": 1.25, "source": "energy_guard", "severity": "error", "code": "energy_balance",
                   "message": "books open", "details": {"residual_j": -0.5}}
    with pytest.raises(ValueError, match="severity = 'fatal'"):
        event_message(0.0, "x", "fatal", "c", "m")
    assert TOPICS["events"].qos.depth >= 100 and TOPICS["events"].resolved().endswith("/events")


def test_energy_fault_event_is_recorded_and_listed_by_the_bag_report(tmp_path, capsys):
    p: Params = preset("s30")
    model = _Leaky(p, 1e-3)
    mapper = MessageMapper(model.layout, "ideal")
    path = tmp_path / "run.mcap"
    rec = McapRecorder(path, metadata=run_metadata(p, preset="s30", model="ideal", dt_s=1e-3, node_parameters={}))
    for key in ("labels", "events", *STEP_TOPICS):
        rec.add_channel(TOPICS[key].resolved(), TOPICS[key].msg_class, TOPICS[key].qos)
    rec.write(TOPICS["labels"].resolved(), mapper.labels(), 0)
    state, reported = model.initial_state(), None
    lead = p.geometry.lead_per_rad_m
    for _ in range(600):
        state, out = model.step(state, 20_000 * lead * 1.5, 20_000.0)
        if out.energy_fault and reported is None:  # what the node does on the first faulty step
            reported = event_message(out.time_s, "energy_guard", "error", "energy_balance", "energy balance violated",
                                     {"residual_j": out.energy_residual_j, "flow_j": out.energy_flow_j})
            rec.write(TOPICS["events"].resolved(), reported, time_ns(out.time_s))
        for topic, msg in mapper.messages(out):
            rec.write(topic, msg, time_ns(out.time_s))
    rec.close()
    assert reported is not None and rec.error is None
    # independent reader
    from rosbags.highlevel import AnyReader
    with AnyReader([path]) as r:
        conns = [c for c in r.connections if c.topic == TOPICS["events"].resolved()]
        docs = [json.loads(r.deserialize(raw, c.msgtype).data) for c, _, raw in r.messages(connections=conns)]
    assert len(docs) == 1 and docs[0]["code"] == "energy_balance" and docs[0]["details"]["flow_j"] > 1.0
    # the bag report lists it
    assert main(["report", str(path), "-o", str(tmp_path / "rep"), "--json", "--no-plots"]) == 0
    events = json.loads(capsys.readouterr().out)["events"]
    assert [e["code"] for e in events] == ["energy_balance"] and events[0]["severity"] == "error"
