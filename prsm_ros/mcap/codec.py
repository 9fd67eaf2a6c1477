"""Where a ROS 2 MCAP file's schema text, type hashes and CDR bytes come from.

A schema must describe exactly the bytes written, so the definitions and the serializer come in
pairs:

- `RclpyCodec` (the node): rclpy's generated classes, serialized by rclpy, described by the .msg
  files and type descriptions of the installed ROS packages (`mcap.schema`). Needs the `ros` extra.
- `TypestoreCodec` (offline runs, no ROS needed): the message dataclasses of a rosbags typestore
  for one ROS 2 distribution, serialized by `rosbags.serde` (the typestore's `serialize_cdr`),
  described by the typestore's own msgdef text and RIHS01 hashes. The definitions are the
  distribution's, shipped with rosbags; nothing is copied into this code.

Both give the same `pkg/msg/Type` names, the same CDR bytes for the same values and the same type
hashes for the types of our interface (`tests/test_offline_mcap.py` compares them when rclpy is
installed); the schema text differs only in what the .msg files carry beyond the definition
(comments, spacing, package-relative type names).
"""

from __future__ import annotations

import os
import struct
from functools import cached_property
from typing import Any
from collections.abc import Mapping

import numpy as np

from prsm_sim.errors import ParamError

from prsm_ros.mcap import schema as mcap_schema

# The typestore used when neither ROS_DISTRO nor an installed rclpy names one: the current LTS.
DEFAULT_DISTRO = "jazzy"


class RclpyCodec:
    """rclpy classes and serializer; definitions from the installed packages' share directories."""

    def __init__(self) -> None:
        from rclpy.serialization import deserialize_message, serialize_message
        self.serialize = serialize_message
        self.deserialize = deserialize_message  # (bytes, message class)
        self.ros_distro: str | None = None  # rosbag2_metadata() finds it from the environment / rclpy

    type_name = staticmethod(mcap_schema.type_name)
    definition = staticmethod(mcap_schema.full_definition)
    type_hash = staticmethod(mcap_schema.type_hash)


def typestore_distro(ros_distro: str | None = None) -> str:
    """The distribution whose typestore to use: given, else $ROS_DISTRO, else the installed rclpy's, else DEFAULT_DISTRO.

    Raises ValueError naming the known distributions when rosbags has no typestore for the name.
    """
    from rosbags.typesys import Stores

    name = (ros_distro or os.environ.get("ROS_DISTRO") or mcap_schema.distro_of_rclpy() or DEFAULT_DISTRO).lower()
    known = [s.value.removeprefix("ros2_") for s in Stores if s.value.startswith("ros2_")]
    if name != "rolling" and name not in known:
        raise ParamError(f"ROS distribution {name!r}: rosbags has message definitions for {', '.join(known)} "
                         "(and rolling)")
    return name


class TypestoreCodec:
    """rosbags typestore classes, CDR serializer, msgdef text and RIHS01 hashes of one ROS 2 distribution."""

    def __init__(self, ros_distro: str | None = None) -> None:
        from rosbags.typesys import Stores, get_typestore

        self.ros_distro = typestore_distro(ros_distro)
        store = Stores.LATEST if self.ros_distro == "rolling" else Stores(f"ros2_{self.ros_distro}")
        self.typestore = get_typestore(store)
        self._definitions: dict[str, str] = {}

    @cached_property
    def classes(self) -> Mapping[str, type]:
        """`pkg/msg/Type` → message dataclass (the kit for `interface.MessageBuilder`)."""
        return self.typestore.types

    @staticmethod
    def float_array(a: np.ndarray) -> np.ndarray:
        """rosbags stores float64[] as a float64 ndarray."""
        return np.ascontiguousarray(a, dtype=np.float64)

    @staticmethod
    def type_name(msg_class) -> str:
        try:
            return msg_class.__msgtype__
        except AttributeError:
            raise mcap_schema.SchemaError(f"{msg_class!r} is not a rosbags message class") from None

    def definition(self, name: str) -> str:
        """The `ros2msg` schema text: the type's definition then each dependency after the 80-`=` delimiter."""
        text = self._definitions.get(name)
        if text is None:
            if name not in self.typestore.fielddefs:
                raise mcap_schema.SchemaError(f"message type {name}: not in the rosbags typestore of "
                                              f"ROS 2 {self.ros_distro}")
            text = self._definitions[name] = self.typestore.generate_msgdef(name, ros_version=2)[0]
        return text

    def type_hash(self, name: str) -> str:
        """The RIHS01 type hash of `pkg/msg/Type` (computed by rosbags from the definition)."""
        return self.typestore.hash_rihs01(name)

    def serialize(self, msg: Any) -> bytes:
        return bytes(self.typestore.serialize_cdr(msg, msg.__msgtype__))

    def deserialize(self, data: bytes, msg_class) -> Any:
        return self.typestore.deserialize_cdr(data, msg_class.__msgtype__)


# bytes of each primitive in CDR (its alignment too)
_PRIMITIVE_SIZE = {"bool": 1, "byte": 1, "char": 1, "int8": 1, "uint8": 1, "int16": 2, "uint16": 2, "int32": 4,
                   "uint32": 4, "float32": 4, "int64": 8, "uint64": 8, "float64": 8}
_ENCAPSULATION = 4  # CDR alignment counts from the end of the encapsulation header


# walk plan operations (`CdrNormaliser._plan`)
_PRIM, _STRING, _PRIM_ARRAY, _PRIM_SEQ, _STRING_SEQ, _ITEMS_ARRAY, _ITEMS_SEQ = range(7)


class CdrNormaliser:
    """CDR bytes with every alignment padding byte zero, the values untouched.

    rclpy's serializer (and a controller's, for the commands the node records as received) leaves
    the padding between fields, and after the last one, uninitialised, so equal messages can differ
    in their bytes; a bag that must be reproducible byte for byte (lockstep runs) writes them
    through this. It walks the message by its definition (a rosbags typestore's field list, turned
    once per type into a flat plan: plain little-endian CDR, primitives aligned to their size,
    strings and sequence lengths to 4) and zeroes the gaps: no decoding. Bytes it cannot walk
    (another encapsulation, a type the typestore lacks, a message cut short) are kept as they are.
    """

    def __init__(self, ros_distro: str | None = None) -> None:
        from rosbags.interfaces import Nodetype

        self._fielddefs = TypestoreCodec(ros_distro).typestore.fielddefs
        self._nodetype = Nodetype
        self._plans: dict[str, list[tuple]] = {}

    def __call__(self, type_name: str, data: bytes) -> bytes:
        if len(data) < _ENCAPSULATION or data[1] != 1:  # CDR_LE only
            return data
        try:
            plan = self._plans.get(type_name)
            if plan is None:
                plan = self._plans[type_name] = self._plan(type_name)
            buf = bytearray(data)
            end = _walk(buf, _ENCAPSULATION, plan)
        except (KeyError, IndexError, struct.error):
            return data
        if end > len(buf):
            return data
        buf[end:] = bytes(len(buf) - end)  # trailing padding
        return bytes(buf)

    def _plan(self, type_name: str) -> list[tuple]:
        """The type's fields as flat operations, nested messages inlined."""
        plan: list[tuple] = []
        for _, node in self._fielddefs[type_name][1]:
            plan += self._node(node)
        return plan

    def _node(self, node) -> list[tuple]:
        nt = self._nodetype
        kind, detail = node
        if kind == nt.BASE:
            return [(_STRING,)] if detail[0] == "string" else [(_PRIM, _PRIMITIVE_SIZE[detail[0]])]
        if kind == nt.NAME:
            return self._plan(detail)
        element, count = detail
        ekind, edetail = element
        if ekind == nt.BASE and edetail[0] in _PRIMITIVE_SIZE:
            return [(_PRIM_SEQ, _PRIMITIVE_SIZE[edetail[0]])] if kind == nt.SEQUENCE else \
                [(_PRIM_ARRAY, _PRIMITIVE_SIZE[edetail[0]], count)]
        if kind == nt.SEQUENCE and ekind == nt.BASE and edetail[0] == "string":
            return [(_STRING_SEQ,)]
        items = self._node(element)
        return [(_ITEMS_SEQ, items)] if kind == nt.SEQUENCE else [(_ITEMS_ARRAY, items, count)]


def _zero_to(buf: bytearray, pos: int, size: int) -> int:
    """Zero the padding from `pos` to the next multiple of `size` (counted after the encapsulation)."""
    aligned = _ENCAPSULATION + (pos - _ENCAPSULATION + size - 1) // size * size
    if aligned != pos:
        if aligned > len(buf):
            raise IndexError(aligned)
        buf[pos:aligned] = bytes(aligned - pos)
    return aligned


def _walk(buf: bytearray, pos: int, plan: list[tuple]) -> int:
    """Zero the padding of one message (or array item) laid out by `plan`; returns where it ends."""
    unpack = struct.unpack_from
    for op in plan:
        code = op[0]
        if code == _PRIM:
            pos = _zero_to(buf, pos, op[1]) + op[1]
        elif code == _STRING:
            pos = _zero_to(buf, pos, 4)
            pos += 4 + unpack("<I", buf, pos)[0]
        elif code == _PRIM_SEQ:
            pos = _zero_to(buf, pos, 4)
            n = unpack("<I", buf, pos)[0]
            pos += 4
            if n:
                pos = _zero_to(buf, pos, op[1]) + op[1] * n
        elif code == _PRIM_ARRAY:
            if op[2]:
                pos = _zero_to(buf, pos, op[1]) + op[1] * op[2]
        elif code == _STRING_SEQ:
            pos = _zero_to(buf, pos, 4)
            n = unpack("<I", buf, pos)[0]
            pos += 4
            for _ in range(n):
                pos = _zero_to(buf, pos, 4)
                pos += 4 + unpack("<I", buf, pos)[0]
        else:
            n = op[2] if code == _ITEMS_ARRAY else None
            if n is None:
                pos = _zero_to(buf, pos, 4)
                n = unpack("<I", buf, pos)[0]
                pos += 4
            for _ in range(n):
                pos = _walk(buf, pos, op[1])
    return pos
