"""Command intake: every message on a command topic or an owned input, decided per writer.

`CommandIntake` takes a command's CDR bytes (from the executor in lockstep, from the step thread's
poll otherwise), refuses it when another participant owns the actuator, records it when it
decodes, offers it to the session's gate, makes an accepted command's sender the owner and has it
echoed by the step that applies it; in lockstep it then advances time (a long request on the jobs
thread, bounded: `step_jobs.LOCKSTEP_BACKLOG_STEPS`). Every refusal is counted per writer and
reported once (`refusals`). Its methods run with the node's lock held.
"""

from __future__ import annotations

import struct

from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from prsm_ros.cdr_read import float64_data, joint_state_stamp_effort0
from prsm_ros.messages import TOPICS, event_message
from prsm_ros.node.command_echo import stamp_of
from prsm_ros.node.joint_commands import offer_joint_command
from prsm_ros.node.outlets import FIRST_COMMAND_READER_WAIT_S
from prsm_ros.node.owned_inputs import OWNED_INPUTS
from prsm_ros.node.ownership import participant_name, participant_of
from prsm_ros.node.refusals import short
from prsm_ros.node.step_jobs import INLINE_STEPS

# the command topics and the interface each commands (joint_commands: the active one; the reference is only recorded)
COMMAND_TOPICS = {"screw_torque": "effort", "velocity_command": "velocity", "position_command": "position",
                  "joint_commands": None, "nut_position_reference": None}


def float64_of(raw: bytes) -> float:
    """A Float64 command's value from its CDR bytes; another encapsulation (big-endian) through rclpy."""
    try:
        return float64_data(raw)
    except ValueError:
        return deserialize_message(raw, Float64).data


def reference_stamp_ns(raw: bytes) -> int | None:
    """The header stamp of a reference's CDR bytes (JointState); None (record it now) when they do not parse."""
    try:
        return joint_state_stamp_effort0(raw)[0]
    except (ValueError, IndexError, struct.error):
        return None


class CommandIntake:
    """Commands and owned inputs into the session, for one node (its ownership, echo, refusals, jobs)."""

    def __init__(self, node, outlets) -> None:
        self.node, self.outlets, self.session = node, outlets, node.session
        self.log = node.get_logger()
        self.names = outlets.topic_names
        cfg = node.config
        # which joint takes which command interface, with the joints' configured names
        self.joints = {"position": cfg.joint_names[1], "velocity": cfg.joint_names[0], "effort": cfg.joint_names[0]}
        # wait_for_controller: paused until the first command accepted from a controller (`hand_over`)
        self.await_controller = cfg.wait_for_controller
        self.readers_awaited = False  # lockstep: the first command waits for its state's readers (Outlets.await_readers)
        self.rerun = node.rerun  # the live Rerun sink or None: the node's sinks are fixed once it is built
        self.lockstep = cfg.time_mode == "lockstep"  # a read-only parameter

    def on_command(self, key: str, raw: bytes, info: dict) -> None:
        """One command message as CDR bytes.

        Refused when another participant owns the actuator (counted, not recorded, and in lockstep
        it does not advance time: a flood from another writer costs a counter per message); else
        recorded when it decodes and offered to the gate, and an accepted command makes its sender
        the owner and is echoed with the step that applies it (every command topic). A reference
        is recorded only (from the owner, or from anyone while nobody owns the actuator).
        """
        node = self.node
        node.superseded.observe(key, info)  # before anything refuses it: the writer's numbering counts every sample
        who = participant_of(info)
        reason = node.ownership.admit(who)
        if reason is not None:
            self.refused(who, "not_owner", f"{self.names[key]}: {reason}")
            return
        if key == "nut_position_reference":
            # at the stamp of the state it answers, not at the moment it arrived (that races the steps)
            self.outlets.record(key, raw, reference_stamp_ns(raw))
            if self.rerun is not None:  # the live recording shows it too, as a bag's conversion does
                self.rerun.submit_reference(raw, self.joints["position"])
            return
        reason, header_ns, malformed = self.offer(key, raw)
        if malformed:  # not this type's CDR: kept out of the bag
            self.refused(who, f"{key}_malformed", f"{self.names[key]}: {reason}")
            return
        self.outlets.record(key, raw)
        if reason is None:
            node.ownership.accepted(who)
            node.echo.offer(stamp_of(header_ns, info.get("source_timestamp")), self.names[key])
            if self.await_controller:
                self.hand_over(key, who)
        else:
            self.refused(who, f"{key}_refused", f"{self.names[key]}: {reason}")
        self.after_command(who)

    def offer(self, key: str, raw: bytes) -> tuple[str | None, int | None, bool]:
        """A command's CDR bytes to the session: (the reason it was refused or None, a JointState's header
        stamp ns, whether the bytes were malformed)."""
        try:
            if key != "joint_commands":
                return self.session.offer(COMMAND_TOPICS[key], float64_of(raw)), None, False
            msg = deserialize_message(raw, JointState)
            arrays = {"position": msg.position, "velocity": msg.velocity, "effort": msg.effort}
            return (offer_joint_command(self.session, msg.name, arrays, self.joints),
                    msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec, False)
        except Exception as e:  # bytes that are not this type's CDR (a raw publisher): refused, never raised
            return self.session.refuse_malformed(f"a {len(raw)}-byte message that is not a valid "
                                                 f"{TOPICS[key].msg_class.__name__} ({type(e).__name__}: {e})"), None, True

    def on_owned_input(self, key: str, msg, info) -> None:
        """~/inject_fault, ~/brake_command (owned_inputs): from the owner, or anyone while nobody owns the actuator."""
        who = participant_of(info)
        reason, code = self.node.ownership.admit(who), f"{key}_not_owner"
        if reason is None:
            self.outlets.record(key, msg)
            reason, code = OWNED_INPUTS[key](self.session, msg), f"{key}_refused"
        if reason is not None:
            self.refused(who, code, f"{self.names[key]}: {reason}")

    def hand_over(self, key: str, who) -> None:
        """wait_for_controller's first accepted command resumes the node (logged, on ~/events)."""
        self.await_controller = False
        self.node.resume()
        text = (f"resumed at t = {self.session.time_s:.6f} s by the first command on {self.names[key]} "
                f"(controller {participant_name(who)})")
        self.log.info(text)
        self.outlets.publish("events", event_message(
            self.session.time_s, "node", "info", "controller_resumed", text,
            {"topic": self.names[key], "participant": participant_name(who)}))

    def refused(self, who: bytes | None, code: str, text: str) -> None:
        """Count a refusal (refusals); the first of a writer for a reason is logged and put on ~/events."""
        writer = participant_name(who)
        if self.node.refusals.refuse(writer, code):
            text = short(text)
            self.log.warning(f"{text} (further refusals of this kind from {writer} are only counted on /diagnostics)")
            self.outlets.publish("events", event_message(self.session.time_s, "refusals", "warn", code, text,
                                                         {"writer": writer}))

    def after_command(self, who: bytes | None) -> None:
        """Lockstep: a command advances time (a long request on the jobs thread, its backlog bounded)."""
        node = self.node
        if not self.lockstep or self.session.paused or node.stopping:
            return
        if not self.readers_awaited:  # once: the first state must reach the controller that asked for it
            self.readers_awaited = True
            if not self.outlets.await_readers(FIRST_COMMAND_READER_WAIT_S):
                self.log.info(f"lockstep: no reader matched on {self.names['joint_states']} within "
                              f"{FIRST_COMMAND_READER_WAIT_S:g} s of the first command; stepping anyway")
        n = node.config.lockstep_steps
        if n <= INLINE_STEPS and not node.jobs.busy:
            node.advance(n, publish_last_state=True)
            return
        refused = node.jobs.refuse_lockstep(n)  # more than a moment of work: on the jobs thread, in slices
        if refused is not None:
            self.refused(who, "lockstep_backlog", refused)
        else:
            node.jobs.submit(n, "lockstep command")
