"""Whether a bag's schema describes what its type name says, for the types the bag tools read by field.

The tools read the node's interface types (JointState, Float64, WrenchStamped, …) by field name;
a foreign bag whose `sensor_msgs/msg/JointState` schema holds some other definition would decode
into an object without those fields. So each definition in such a schema (the type and the
types it embeds) is compared, field by field (name, base type, array or not), with the standard
definition of the same name: the rosbags typestore's (the `bag` extra), else the installed ROS
packages'. With neither available the schema is taken as it is.

Only the schema text is parsed (field lines, here); nothing named by it is imported.
"""

from __future__ import annotations

import re
from functools import cache

from prsm_sim.errors import InputError

from prsm_ros.interface import TOPIC_DEFS

CDR = "cdr"
ROS2MSG = "ros2msg"
_DELIMITER = re.compile(r"^=+[ \t\r]*$", re.M)
_MSG_LINE = re.compile(r"^\s*MSG:\s*(\S+)")
# TYPE[<=N][ARRAY] NAME[ DEFAULT | =VALUE]: the field and constant lines of the .msg language (rosidl)
_FIELD = re.compile(r"(?P<type>[A-Za-z][A-Za-z0-9_]*(?:/[A-Za-z][A-Za-z0-9_]*)?)(?:<=\d+)?"
                    r"(?P<array>\[(?:<=)?\d*\])?\s+(?P<name>[A-Za-z][A-Za-z0-9_]*)(?P<rest>\s*=.*|\s+.*|)")
MAX_SCHEMA_BYTES = 1 << 20  # a definition with its dependencies is a few KB
# Types nested in types: the decoder recurses once per level (JointState nests 3 deep), and a type
# that contains itself (through a sequence) lets the data choose the depth.
MAX_SCHEMA_NESTING = 32
_BUILTIN = frozenset({"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16", "int32",
                      "uint32", "int64", "uint64", "string", "wstring", "time", "duration"})


def _split(name: str) -> tuple[str, str]:
    parts = name.split("/")
    return parts[0], parts[-1]


def _normal(name: str) -> str:
    pkg, typ = _split(name)
    return f"{pkg}/msg/{typ}"


def sections(name: str, text: str) -> dict[str, str]:
    """`pkg/msg/Type` → its definition text, for the schema's own type and each `MSG:` section."""
    parts = _DELIMITER.split(text)
    out = {_normal(name): parts[0]}
    for part in parts[1:]:
        m = _MSG_LINE.search(part)
        if m:
            out[_normal(m.group(1))] = part[m.end():]
    return out


def signature(name: str, text: str) -> tuple:
    """(field name, base type, is array) of each field of one `.msg` definition; InputError (a ValueError) naming the
    first line that is neither a field, a constant, a comment nor blank.

    The base type drops the package (`std_msgs/Header` and a package-relative `Header` are the same
    type), string bounds and array sizes; constants are not fields.
    """
    fields = []
    for number, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        m = _FIELD.fullmatch(line)
        if m is None:
            raise InputError(f"line {number} is not a field")
        if m.group("rest").startswith("="):  # a constant: NAME=VALUE
            continue
        fields.append((m.group("name"), m.group("type").rsplit("/", 1)[-1], m.group("array") is not None))
    return tuple(fields)


@cache
def _reference_text(name: str) -> str | None:
    try:
        from prsm_ros.mcap.codec import TypestoreCodec
        return TypestoreCodec().definition(name)
    except Exception:  # rosbags missing, or the type not in its store: try the installed packages
        pass
    try:
        from prsm_ros.mcap.schema import full_definition
        return full_definition(name)
    except Exception:
        return None


@cache
def reference_signatures() -> dict[str, tuple]:
    """Signatures of the interface's types and the types they embed, from the standard definitions."""
    out: dict[str, tuple] = {}
    for t in {d.type_name for d in TOPIC_DEFS.values()}:
        text = _reference_text(t)
        if text is None:
            continue
        for sub, body in sections(t, text).items():
            try:
                out.setdefault(sub, signature(sub, body))
            except ValueError:
                continue
    return out


def _references(section: str, body: str) -> set[str]:
    """The message types the fields of one section embed, as pkg/msg/Type (package-relative names resolved)."""
    pkg = section.split("/")[0]
    out = set()
    for line in body.splitlines():
        m = _FIELD.fullmatch(line.split("#", 1)[0].strip())
        if m is None or m.group("rest").startswith("=") or m.group("type") in _BUILTIN:
            continue
        t = m.group("type")
        out.add(_normal(t) if "/" in t else "std_msgs/msg/Header" if t == "Header" else f"{pkg}/msg/{t}")
    return out


def nesting_problem(name: str, text: str) -> str | None:
    """Why the types of a schema cannot be decoded with a bounded depth (a type containing itself, or
    nesting deeper than MAX_SCHEMA_NESTING); None when they can. Walked without recursion."""
    refs = {sub: _references(sub, body) for sub, body in sections(name, text).items()}
    root = _normal(name)
    path: list[tuple[str, list[str]]] = [(root, sorted(refs.get(root, ())))]
    on_path = {root}
    done: set[str] = set()
    while path:
        node, todo = path[-1]
        if not todo:
            path.pop()
            on_path.discard(node)
            done.add(node)
            continue
        nxt = todo.pop()
        if nxt in on_path:
            return f"its type {nxt} contains itself"
        if nxt in done:
            continue
        if len(path) >= MAX_SCHEMA_NESTING:
            return f"its types nest more than {MAX_SCHEMA_NESTING} deep"
        path.append((nxt, sorted(refs.get(nxt, ()))))
        on_path.add(nxt)
    return None


def schema_problem(message_encoding: str, schema) -> str | None:
    """Why messages with this encoding and schema cannot be decoded as their type says; None when they can."""
    if message_encoding != CDR:
        return f"message encoding {message_encoding[:40]!r}, not {CDR}"
    if schema is None:
        return "no schema"
    if schema.encoding != ROS2MSG:
        return f"schema encoding {schema.encoding[:40]!r}, not {ROS2MSG}"
    if len(schema.data) > MAX_SCHEMA_BYTES:
        return f"a schema of {len(schema.data)} bytes (more than {MAX_SCHEMA_BYTES >> 10} KiB)"
    try:
        text = schema.data.decode("utf-8")
    except UnicodeDecodeError:
        return "its schema is not UTF-8 text"
    if schema.name.count("/") not in (1, 2):
        return f"schema name {schema.name[:80]!r} is not pkg/msg/Type"
    nesting = nesting_problem(schema.name, text)
    if nesting is not None:
        return nesting
    reference = reference_signatures()
    for sub, body in sections(schema.name, text).items():
        expected = reference.get(sub)
        if expected is None:
            continue
        try:
            got = signature(sub, body)
        except ValueError as e:
            return f"its definition of {sub} does not parse ({e})"
        if got != expected:
            fields = ", ".join(f for f, _, _ in got[:6]) or "none"
            return f"its definition of {sub} is not the standard one (fields: {fields})"
    return None
