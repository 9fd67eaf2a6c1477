"""ROS 2 MCAP profile pieces: `ros2msg` schema text and the `offered_qos_profiles` channel metadata.

What rosbag2's MCAP storage plugin writes, and what every reader of the profile (rosbag2, Foxglove,
Rerun, mcap_ros2, rosbags) expects (MCAP spec, "ROS 2" profile; rosbag2_storage_mcap):

- schema name `pkg/msg/Type`, encoding `ros2msg`, data = the type's .msg text followed by every type
  it depends on, each after a line of 80 `=` and `MSG: pkg/Type`, each type once;
- channel metadata `offered_qos_profiles`: a YAML list of QoS profiles with integer enums (history
  1 = keep last, 2 = keep all; reliability 1 = reliable, 2 = best effort; durability 1 = transient
  local, 2 = volatile; liveliness 1 = automatic), durations as {sec, nsec}. rosbag2 metadata
  version 9 switched to enum names, but every distro still reads the integers (rosbag2 reads
  integers when the file carries no serialized rosbag2 metadata; see `rosbag2_metadata()`);
- channel metadata `topic_type_hash`: the RIHS01 type hash (Iron and later), read from the
  package's generated type description.

For rclpy messages (the node) the definitions are read at run time from the installed packages'
share directories (ament index, else `<prefix>/share/<pkg>/msg/`), never copied into this code;
offline writing without ROS takes them from a rosbags typestore (`prsm_ros.mcap.codec`). Nothing
here imports rclpy except `qos_from_yaml`, which builds an rclpy QoSProfile for `prsm-bag play`.
"""

from __future__ import annotations

import json
import os
import re
import sys
from functools import cache
from pathlib import Path

from prsm_sim.errors import PrsmError

SCHEMA_ENCODING = "ros2msg"
MESSAGE_ENCODING = "cdr"
PROFILE = "ros2"
DELIMITER = "=" * 80

# Primitive field types of the ROS 2 .msg language (rosidl); anything else names a message type.
_PRIMITIVES = frozenset({
    "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
    "int32", "uint32", "int64", "uint64", "string", "wstring",
})
# A field or constant line: type (with optional array/bound suffix) then a name.
_FIELD_TYPE = re.compile(r"^\s*([A-Za-z][A-Za-z0-9_/]*)(?:<=\d+)?(?:\[[^\]]*\])?\s+\S")

# What DDS reports for a policy left at "default": rosbag2 records the reported offer, so an
# unspecified duration appears as RMW_DURATION_INFINITE and the system-default liveliness as automatic.
_DURATION_INFINITE = {"sec": 9223372036, "nsec": 854775807}
_LIVELINESS_AUTOMATIC = 1
_HISTORY_KEEP_LAST = 1


class SchemaError(PrsmError, LookupError):
    """A message definition could not be found or understood; the message names the type and where it looked."""


# The ROS message packages a class may be imported from by its type name (those of the node's interface, the
# `ros` extra): a bag's schema or a writer's channel names a package, and importing it would run whatever
# module of that name is on the path.
MESSAGE_PACKAGES = frozenset({"std_msgs", "sensor_msgs", "geometry_msgs", "diagnostic_msgs", "rosgraph_msgs",
                              "builtin_interfaces"})
_TYPE_NAME = re.compile(r"[A-Z][A-Za-z0-9]*")


def message_class(type_name: str):
    """The rclpy message class of `pkg/msg/Type`; None when `pkg` is not one of MESSAGE_PACKAGES or not installed."""
    import importlib
    parts = type_name.split("/")
    if len(parts) != 3 or parts[1] != "msg" or parts[0] not in MESSAGE_PACKAGES or not _TYPE_NAME.fullmatch(parts[2]):
        return None
    try:
        cls = getattr(importlib.import_module(f"{parts[0]}.msg"), parts[2])
    except (ImportError, AttributeError):
        return None
    return cls if isinstance(cls, type) else None


def type_name(msg_class) -> str:
    """`pkg/msg/Type` for a generated rclpy message class (e.g. std_msgs.msg.Float64 → std_msgs/msg/Float64)."""
    module = msg_class.__module__  # e.g. "std_msgs.msg._float64"
    parts = module.split(".")
    if len(parts) < 2 or parts[1] != "msg":
        raise SchemaError(f"{msg_class!r} is not a generated ROS 2 message class (module {module})")
    return f"{parts[0]}/msg/{msg_class.__name__}"


def _split_type(name: str) -> tuple[str, str]:
    """(package, Type) from `pkg/msg/Type` or `pkg/Type`."""
    parts = name.split("/")
    if len(parts) == 3 and parts[1] == "msg":
        return parts[0], parts[2]
    if len(parts) == 2:
        return parts[0], parts[1]
    raise SchemaError(f"message type {name!r}: expected pkg/msg/Type or pkg/Type")


def share_dirs(package: str) -> list[Path]:
    """Candidate share directories of `package`: the ament index first, then this interpreter's prefixes."""
    out: list[Path] = []
    if os.environ.get("AMENT_PREFIX_PATH"):
        try:
            from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
        except ImportError:  # the ament index is not installed: only the prefixes below
            pass
        else:
            try:
                out.append(Path(get_package_share_directory(package)))
            except PackageNotFoundError:  # not indexed there: fall through to the prefixes
                pass
    for prefix in dict.fromkeys((sys.prefix, sys.base_prefix)):
        out.append(Path(prefix) / "share" / package)
    return out


def _definition_file(package: str, type_: str, suffix: str) -> Path:
    for d in share_dirs(package):
        f = d / "msg" / f"{type_}{suffix}"
        if f.is_file():
            return f
    looked = ", ".join(str(d / "msg") for d in share_dirs(package))
    raise SchemaError(f"no {type_}{suffix} for message type {package}/msg/{type_} (looked in {looked})")


@cache
def msg_text(package: str, type_: str) -> str:
    """The .msg text of `package/Type` exactly as installed."""
    return _definition_file(package, type_, ".msg").read_text(encoding="utf-8")


def dependencies(text: str, package: str) -> list[str]:
    """Message types (`pkg/Type`) that the fields of a .msg text refer to, sorted, comments ignored.

    A bare `Type` means a type of the same package (rosidl's rule); `Header` without a package is
    the ROS 1 spelling of std_msgs/Header and does not occur in ROS 2 definitions.
    """
    deps: set[str] = set()
    for line in text.splitlines():
        line = line.split("#", 1)[0]
        m = _FIELD_TYPE.match(line)
        if not m:
            continue
        t = m.group(1)
        if t in _PRIMITIVES:
            continue
        deps.add(t if "/" in t else f"{package}/{t}")
    return sorted(deps)


@cache
def full_definition(name: str) -> str:
    """The `ros2msg` schema text of a type: its .msg text then each dependency once, depth first.

    Each dependency follows a newline, a line of 80 `=`, and `MSG: pkg/Type` (the layout rosbag2
    writes and mcap_ros2 / rosbags / Foxglove parse).
    """
    seen: set[str] = set()

    def expand(pkg_type: str, depth: int) -> str:
        if depth > 50:
            raise SchemaError(f"message type {name}: dependency chain deeper than 50 types")
        package, type_ = _split_type(pkg_type)
        text = msg_text(package, type_)
        for dep in dependencies(text, package):
            if dep not in seen:
                seen.add(dep)
                text += f"\n{DELIMITER}\nMSG: {dep}\n" + expand(dep, depth + 1)
        return text

    return expand(name, 0)


@cache
def type_hash(name: str) -> str:
    """The RIHS01 type hash of `pkg/msg/Type` from its generated type description, "" when absent."""
    package, type_ = _split_type(name)
    try:
        desc = json.loads(_definition_file(package, type_, ".json").read_text(encoding="utf-8"))
    except (SchemaError, OSError, ValueError):
        return ""
    full = f"{package}/msg/{type_}"
    for entry in desc.get("type_hashes", []):
        if entry.get("type_name") == full:
            return str(entry.get("hash_string", ""))
    return ""


def _duration(d) -> dict[str, int]:
    ns = 0 if d is None else int(d.nanoseconds)
    if ns <= 0:  # 0 = "default": the middleware offers infinity
        return dict(_DURATION_INFINITE)
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def qos_dict(qos) -> dict:
    """One QoS profile as rosbag2 records an offer (integer enums, {sec, nsec} durations).

    `qos`: an rclpy QoSProfile, or an `interface.QosSpec` (plain data: deadline, lifespan and
    liveliness at their defaults, as for every topic of our interface).
    """
    history = int(qos.history) or _HISTORY_KEEP_LAST  # 0 = system default, which is keep last
    return {
        "history": history,
        "depth": int(qos.depth),
        "reliability": int(qos.reliability),
        "durability": int(qos.durability),
        "deadline": _duration(getattr(qos, "deadline", None)),
        "lifespan": _duration(getattr(qos, "lifespan", None)),
        "liveliness": int(getattr(qos, "liveliness", 0)) or _LIVELINESS_AUTOMATIC,
        "liveliness_lease_duration": _duration(getattr(qos, "liveliness_lease_duration", None)),
        "avoid_ros_namespace_conventions": bool(getattr(qos, "avoid_ros_namespace_conventions", False)),
    }


def offered_qos_profiles_yaml(*profiles) -> str:
    """The `offered_qos_profiles` channel metadata value: a YAML list, one entry per offered profile."""
    import yaml
    return yaml.safe_dump([qos_dict(q) for q in profiles], sort_keys=False, default_flow_style=False).rstrip("\n")


MAX_QOS_DEPTH = 10_000  # a recorded keep-last depth beyond this (or not a whole number) is read as the default 10


def _whole(v) -> int | None:
    """A recorded whole number (int, or text of one); None for anything else (1e400, 'x', 2.5, a list)."""
    if isinstance(v, bool):
        return None
    if isinstance(v, int):
        return v
    if isinstance(v, str) and v.strip().lstrip("+-").isdigit() and len(v) < 30:
        return int(v)
    return None


def qos_from_yaml(text: str):
    """The first offered profile of an `offered_qos_profiles` value as an rclpy QoSProfile.

    Accepts the integer form and the enum-name form of rosbag2 metadata version 9; an empty or
    unreadable value gives rclpy's default (reliable, volatile, keep last 10).
    """
    from rclpy.duration import Duration
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    from prsm_ros.limits import load_yaml
    try:
        items = load_yaml(text, source="offered_qos_profiles") if text else None
    except ValueError:
        items = None
    if not items or not isinstance(items, list) or not isinstance(items[0], dict):
        return QoSProfile(depth=10)
    p = items[0]

    def enum(policy, value, default):
        if isinstance(value, int):
            try:
                return policy(value)
            except ValueError:
                return default
        if isinstance(value, str):
            return policy.__members__.get(value.upper(), default)
        return default

    history = enum(HistoryPolicy, p.get("history"), HistoryPolicy.KEEP_LAST)
    if history not in (HistoryPolicy.KEEP_LAST, HistoryPolicy.KEEP_ALL):
        history = HistoryPolicy.KEEP_LAST
    depth = _whole(p.get("depth"))
    depth = depth if depth is not None and 1 <= depth <= MAX_QOS_DEPTH else 10
    kw = {}
    for key in ("deadline", "lifespan"):
        d = p.get(key)
        if isinstance(d, dict) and {"sec": d.get("sec"), "nsec": d.get("nsec")} != _DURATION_INFINITE:
            sec, nsec = _whole(d.get("sec", 0)), _whole(d.get("nsec", 0))
            ns = None if sec is None or nsec is None else sec * 1_000_000_000 + nsec
            if ns is not None and 0 < ns < 2**62:
                kw[key] = Duration(nanoseconds=ns)
    return QoSProfile(
        history=history, depth=depth,
        reliability=enum(ReliabilityPolicy, p.get("reliability"), ReliabilityPolicy.RELIABLE),
        durability=enum(DurabilityPolicy, p.get("durability"), DurabilityPolicy.VOLATILE),
        **kw,
    )


def rosbag2_metadata(ros_distro: str | None = None) -> dict[str, str]:
    """The `rosbag2` metadata record in its pre-Jazzy form: the ROS distribution and nothing else.

    rosbag2 (Jazzy and later) reads a `rosbag2` record without `serialized_metadata` as metadata
    version 8 and therefore parses `offered_qos_profiles` in the integer form written here; without
    any `rosbag2` record it would assume its newest version and expect enum names. Humble and Iron
    wrote exactly this record.
    """
    return {"ROS_DISTRO": ros_distro or os.environ.get("ROS_DISTRO") or distro_of_rclpy()}


def distro_of_rclpy() -> str:
    """The ROS 2 distribution of the installed rclpy (major version → distro), "" if unknown.

    Read from the package metadata: rclpy itself is not imported.
    """
    from importlib.metadata import PackageNotFoundError, version
    try:
        major = int(version("rclpy").split(".")[0])
    except (PackageNotFoundError, ValueError):  # not installed, or a version we cannot read
        return ""
    return {3: "humble", 4: "iron", 7: "jazzy", 9: "kilted", 10: "rolling"}.get(major, "")
