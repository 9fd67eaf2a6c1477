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


class CdrNormaliser:
    """CDR bytes with every alignment padding byte zero, the values untouched.

    rclpy's serializer (and a controller's, for the commands the node records as received) leaves
    the padding between fields, and after the last one, uninitialised, so equal messages can differ
    in their bytes; a bag that must be reproducible byte for byte (lockstep runs) writes them
    through this. Where the padding lies comes from the message's definition (`cdr_layout`, a
    rosbags typestore's field list): no decoding, and one walk per shape of message, not per
    message. Bytes it cannot walk (another encapsulation, a type the typestore lacks, a message
    cut short) are kept as they are. `layouts` is also what `McapFile.check` asks.
    """

    def __init__(self, ros_distro: str | None = None) -> None:
        from rosbags.interfaces import Nodetype

        from prsm_ros.mcap.cdr_layout import Layouts

        self.layouts = Layouts(TypestoreCodec(ros_distro).typestore.fielddefs, Nodetype)

    def __call__(self, type_name: str, data: bytes) -> bytes:
        lay = self.layouts.layout(type_name, data)
        return data if lay is None else lay.zero_padding(data)
