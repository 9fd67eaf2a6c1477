"""`prsm-bag play`: republish a bag's messages onto ROS topics in real time × a rate factor.

Messages go out as recorded (the CDR bytes, no decoding) on publishers with each channel's
recorded QoS (`offered_qos_profiles`; latched topics stay latched), paced on absolute deadlines
from the bag's log times. `/clock` carries the bag time: a recorded `/clock` topic is played like
any other; when it is not played (absent, or not selected), a Clock with the current bag time is
published before each new log time
(the simulator's convention: the bag time is the simulation time), so nodes with
use_sim_time follow the playback. Only the message packages of the node's interface
(`schema.MESSAGE_PACKAGES`) are ever imported, never a package named by the bag; topics of other types,
and topics whose messages cannot be decoded, are skipped and reported. Each message is decoded
before it is sent (rclpy's deserializer), so a malformed one is skipped and counted rather than
handed to subscribers.
"""

from __future__ import annotations

import time

from prsm_ros.mcap import schema as mcap_schema
from prsm_ros.bag.reader import Bag, BagError


WAIT_FOR_SUBSCRIBERS_S = 30.0
MAX_PLAY_WALL_S = 86_400.0  # one playback's length in wall time (log-time span / rate): longer is refused up front
MAX_DELAY_S = 3600.0


def _wait_for_subscribers(pubs: dict, context, timeout_s: float) -> None:
    import rclpy
    end = time.monotonic() + timeout_s
    missing = list(pubs)
    while time.monotonic() < end and rclpy.ok(context=context):
        missing = [t for t, p in pubs.items() if p.get_subscription_count() == 0]
        if not missing:
            return
        time.sleep(0.02)
    raise BagError(f"no subscriber appeared within {timeout_s:g} s on {', '.join(missing)} "
                   "(drop --wait-for-subscribers to play regardless)")


def _why_skipped(bag: Bag, topic: str) -> str:
    info = bag.topics[topic]
    if info.problem:
        return f"{info.type or 'no schema'}: {info.problem}"
    package = info.type.split("/")[0]
    if package not in mcap_schema.MESSAGE_PACKAGES:
        return f"{info.type}: play publishes only the types of {', '.join(sorted(mcap_schema.MESSAGE_PACKAGES))}"
    return f"{info.type}: message package not installed"


def _bad_name(topic: str) -> str | None:
    """Why `topic` cannot be a ROS topic name (rclpy's rules: characters, length ≤ 247); None when it can."""
    from rclpy.exceptions import NameValidationException
    from rclpy.validate_full_topic_name import validate_full_topic_name
    try:
        validate_full_topic_name(topic)
    except NameValidationException as e:
        return f"not a valid ROS topic name ({str(e).splitlines()[0][:100]})"
    return None


def _check_wall_time(bag: Bag, topics: list[str], start_ns: int | None, end_ns: int | None, rate: float) -> None:
    """BagError up front when playing `topics` between the bounds would take over MAX_PLAY_WALL_S."""
    firsts = [bag.topics[t].first_ns for t in topics if bag.topics[t].first_ns is not None]
    lasts = [bag.topics[t].last_ns for t in topics if bag.topics[t].last_ns is not None]
    if not firsts or not lasts:
        return
    lo = max(min(firsts), start_ns) if start_ns is not None else min(firsts)
    hi = min(max(lasts), end_ns) if end_ns is not None else max(lasts)
    span_s = max(hi - lo, 0) * 1e-9
    if span_s / rate > MAX_PLAY_WALL_S:
        raise BagError(f"{bag.path.name}: its log times span {span_s:.6g} s, {span_s / rate:.3g} s of playback at "
                       f"--rate {rate:g}: more than {MAX_PLAY_WALL_S:g} s; raise --rate to at least "
                       f"{span_s / MAX_PLAY_WALL_S:.3g} or narrow --start/--end")


def _playable(bag: Bag, selected: list[str]) -> tuple[dict, dict, list[str]]:
    """(topic → message class or None, skipped topic → why, playable topics) of a selection."""
    classes = {t: None if bag.topics[t].problem or _bad_name(t) else mcap_schema.message_class(bag.topics[t].type)
               for t in selected}
    skipped = {t: _bad_name(t) or _why_skipped(bag, t) for t, c in classes.items() if c is None}
    playable = [t for t in selected if classes[t] is not None]
    if not playable:
        raise BagError(f"{bag.path.name}: none of the selected topics can be played "
                       f"({'; '.join(f'{t} ({why})' for t, why in skipped.items())})")
    return classes, skipped, playable


def _publish(bag: Bag, messages, classes: dict, pubs: dict, clock_pub, rate: float, counts: dict) -> tuple[float, int]:
    """Publish `messages` on `pubs` paced at `rate` (and a Clock per new log time on `clock_pub`);
    returns the wall time taken and the clocks published. Counts what it sent in `counts`."""
    from rclpy.serialization import deserialize_message
    from rosgraph_msgs.msg import Clock
    wall0 = t_first = last_clock = None
    clock_count = 0
    for m in messages:
        try:  # rclpy's own deserializer: what a subscriber would do with the bytes, ~100× mcap_ros2's speed
            deserialize_message(m.data, classes[m.topic])
        except Exception as e:  # the middleware's error types for bytes it cannot read
            bag.count_malformed(m.topic, m.log_time_ns, len(m.data), str(e) or type(e).__name__)
            continue
        if t_first is None:
            t_first, wall0 = m.log_time_ns, time.monotonic()
        due = wall0 + (m.log_time_ns - t_first) * 1e-9 / rate
        if due - wall0 > MAX_PLAY_WALL_S:  # the topics' recorded time ranges understated the span
            raise BagError(f"{bag.path.name}: message at log time {m.log_time_ns * 1e-9:.9g} s is due "
                           f"{due - wall0:.3g} s into the playback, beyond {MAX_PLAY_WALL_S:g} s; stopped")
        wait = due - time.monotonic()
        if wait > 0:
            time.sleep(wait)
        if clock_pub is not None and m.log_time_ns != last_clock:
            c = Clock()
            c.clock.sec, c.clock.nanosec = divmod(m.log_time_ns, 1_000_000_000)
            clock_pub.publish(c)
            clock_count += 1
            last_clock = m.log_time_ns
        pubs[m.topic].publish(m.data)
        counts[m.topic] += 1
    return (time.monotonic() - wall0 if wall0 is not None else 0.0), clock_count


def play(bag: Bag, *, rate: float = 1.0, start_s: float | None = None, end_s: float | None = None,
         topics: list[str] | None = None, clock: bool = True, delay_s: float = 0.5,
         wait_for_subscribers: bool = False, progress: bool = True, node_name: str = "prsm_bag_play") -> dict:
    """Publish the selection; returns counts per topic, skipped topics and the wall time taken.

    `delay_s`: pause after creating the publishers (discovery). `wait_for_subscribers`: then also
    wait, up to WAIT_FOR_SUBSCRIBERS_S, until every played topic has a matched subscription.
    """
    if not (rate > 0 and rate < float("inf")):
        raise BagError(f"--rate {rate!r}: must be a number > 0 (1 = real time)")
    if not 0 <= delay_s <= MAX_DELAY_S:
        raise BagError(f"--delay {delay_s!r}: must be 0 to {MAX_DELAY_S:g} s")
    selected = list(topics) if topics else sorted(bag.topics)
    bag.require_topics(selected)
    start_ns, end_ns = bag.window_ns(start_s, end_s)
    _check_wall_time(bag, selected, start_ns, end_ns, rate)

    try:
        import rclpy
        from rclpy.impl.implementation_singleton import rclpy_implementation
        from rosgraph_msgs.msg import Clock
    except ModuleNotFoundError as e:  # an install without the ros extra (pip install 'prsm[bag]')
        raise BagError(f"play publishes on ROS topics and needs rclpy and the ROS message packages "
                       f"({e.name} is not installed): pip install 'prsm[ros]'") from None

    classes, skipped, playable = _playable(bag, selected)
    counts = {t: 0 for t in playable}
    context = rclpy.Context()
    try:
        rclpy.init(context=context)
    except rclpy_implementation.RCLError as e:  # the environment's ROS settings (ROS_DOMAIN_ID, …)
        raise BagError(f"play: ROS could not start ({str(e).splitlines()[0][:160]})") from None
    try:
        node = rclpy.create_node(node_name, context=context)
        pubs = {t: node.create_publisher(classes[t], t, mcap_schema.qos_from_yaml(bag.topics[t].qos_yaml))
                for t in playable}
        clock_pub = node.create_publisher(Clock, "/clock", 10) if clock and "/clock" not in playable else None
        time.sleep(delay_s)  # let subscribers discover the new publishers before the first message
        if wait_for_subscribers:
            _wait_for_subscribers(pubs, context, WAIT_FOR_SUBSCRIBERS_S)
        messages = bag.messages(playable, start_ns, end_ns, decode=False, progress=progress, desc="playing")
        wall, clock_count = _publish(bag, messages, classes, pubs, clock_pub, rate, counts)
        time.sleep(min(delay_s, 0.5))  # reliable writers: give the last samples time to be delivered
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
    if clock_pub is not None:
        counts["/clock (from bag time)"] = clock_count
    return {"published": counts, "skipped": skipped, "wall_time_s": wall, "rate": rate}
