"""The node's services (std_srvs): pause, step, reset, release_control, brake, clear_faults.

`NodeServices` answers each request under the node's lock. Every answer says what happened
(`success` false with the reason for a refusal); a request can never end the executor: an
unexpected error in a handler is logged and answered as a failure (`guarded`), the node goes on.
"""

from __future__ import annotations

import functools

from std_srvs.srv import SetBool, Trigger

from prsm_ros.messages import event_message
from prsm_ros.node.ownership import participant_name
from prsm_ros.node.refusals import short
from prsm_ros.node.step_jobs import INLINE_WAIT_S, STEP_REQUEST, answer, done_event, request_refused


def guarded(handler):
    """A service handler whose unexpected errors become a failed answer and an error log line."""
    @functools.wraps(handler)
    def call(self, request, response):
        try:
            return handler(self, request, response)
        except Exception as e:
            text = short(f"{handler.__name__.removeprefix('srv_')} failed: {type(e).__name__}: {e}")
            self.node.get_logger().error(text)
            response.success, response.message = False, text
            return response
    return call


class NodeServices:
    """The services of one node (its session, lock, jobs, ownership, outlets)."""

    def __init__(self, node, outlets) -> None:
        self.node, self.outlets, self.session = node, outlets, node.session
        for srv_type, name, callback in ((SetBool, "~/pause", self.srv_pause), (Trigger, "~/step", self.srv_step),
                                         (Trigger, "~/reset", self.srv_reset),
                                         (Trigger, "~/release_control", self.srv_release_control),
                                         (SetBool, "~/brake", self.srv_brake),
                                         (Trigger, "~/clear_faults", self.srv_clear_faults)):
            node.create_service(srv_type, name, callback)

    @guarded
    def srv_pause(self, request, response):
        with self.node.lock:
            self.node.pause() if request.data else self.node.resume()
            response.success = True
            response.message = f"{'paused' if self.session.paused else 'running'} at t = {self.session.time_s:.6f} s"
        return response

    @guarded
    def srv_step(self, request, response):
        """`step_count` steps on the jobs thread: answered when done within INLINE_WAIT_S, else "accepted"
        at once and a `step_done` event when they end (step_jobs)."""
        node = self.node
        with node.lock:
            refused = request_refused(self.session, node.jobs)
            if refused:
                response.success, response.message = False, refused
                return response
            job = node.jobs.submit(node.config.step_count, STEP_REQUEST)
        response.success, response.message = answer(job, node.jobs.wait_or_detach(job, INLINE_WAIT_S),
                                                     self.session.time_s)
        return response

    def step_job_done(self, job) -> None:
        """Jobs thread: a request answered "accepted" has ended: an event says how."""
        with self.node.lock:
            msg = event_message(self.session.time_s, "step", **done_event(job, self.session.time_s))
            self.outlets.publish("events", msg)

    @guarded
    def srv_reset(self, request, response):
        node = self.node
        with node.lock:
            x = node.config.initial_nut_position  # checked against the threads when it was set
            self.session.reset(x)
            node.echo.reset()
            node.superseded.reset()
            node.reporter.rearm()
            node.pacer.restart()
            if self.session.paused:  # nothing steps while paused: a controller still sees the reset now
                self.outlets.publish_rest_state()
            response.success = True
            response.message = f"reset to t = 0, nut at {x:g} m"
        node.get_logger().info(response.message)
        return response

    @guarded
    def srv_release_control(self, request, response):
        with self.node.lock:
            response.message = self.node.ownership.release()
            response.success = True
        self.node.get_logger().info(f"~/release_control: {response.message}")
        return response

    @guarded
    def srv_brake(self, request, response):
        """The brake by service, while nobody owns the actuator: rclpy does not say who calls a
        service, so an owned actuator brakes through ~/brake_command from its owner."""
        with self.node.lock:
            owner = self.node.ownership.owner_now()
            if owner is not None:
                response.success = False
                response.message = (f"the actuator is owned by {participant_name(owner)}: its owner engages the "
                                    f"brake on {self.outlets.topic_names['brake_command']} (std_msgs/Bool)")
                return response
            reason = self.session.brake(bool(request.data))
            response.success = reason is None
            response.message = reason or (f"brake {'engaging' if request.data else 'releasing'} "
                                          f"at t = {self.session.time_s:.6f} s")
        return response

    @guarded
    def srv_clear_faults(self, request, response):
        with self.node.lock:
            n = self.session.clear_faults()
            response.success = True
            response.message = f"{n} runtime fault(s) ended at t = {self.session.time_s:.6f} s"
        return response
