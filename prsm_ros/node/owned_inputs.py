"""The actuator inputs besides commands that are owned like them: a fault to inject, the brake.

Each takes the Session and the received message and returns the refusal reason, or None when
done. The node admits the writer first (`CommandOwnership.admit`: the owner, or anyone while
nobody owns the actuator); neither input takes ownership, only a valid command does.
"""

from __future__ import annotations

from prsm_sim import PrsmError


def inject_fault(session, msg) -> str | None:
    """~/inject_fault (String 'kind=…,start_s=…,duration_s=…,value=…'; start_s in simulation time, omitted: now)."""
    from prsm_sim.actuator import parse_fault

    from prsm_ros.node.parameters import bound_fault  # fault values bounded like commands
    text = msg.data if "start_s" in msg.data else f"{msg.data},start_s={session.time_s!r}"
    try:
        return session.inject(bound_fault(parse_fault(text)))
    except PrsmError as e:
        return str(e)


def brake(session, msg) -> str | None:
    """~/brake_command (Bool): true engages the brake, false releases it."""
    return session.brake(bool(msg.data))


# topic key → what it does
OWNED_INPUTS = {"inject_fault": inject_fault, "brake_command": brake}
