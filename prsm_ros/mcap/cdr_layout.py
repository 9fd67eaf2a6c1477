"""Where the padding, the length fields and the strings of a CDR message lie, learnt once per shape.

A message's layout in plain little-endian CDR (primitives aligned to their size, strings and
sequence lengths to 4, counted after the 4-byte encapsulation header) follows from its definition
and from the lengths it carries: the same type with the same length fields is laid out the same
way whatever its numbers. The node's per-step messages and a controller's commands and references
keep one shape for a whole run, so a `Layouts` walks a message by its definition (a rosbags
typestore's field list, turned once per type into a flat plan) only for a shape it has not seen;
for a known one it compares the length fields and reuses what the walk found:

- `padding`: the alignment gaps, which rclpy's serializer leaves uninitialised (a reproducible bag
  zeroes them: `codec.CdrNormaliser`);
- `decisive`: the bytes on which decoding can fail: the encapsulation header, the lengths, the
  strings' bytes, booleans (fast-cdr refuses a value other than 0 or 1) and anything after the
  message. Numbers cannot make a message undecodable, so bytes whose decisive part equals that of
  bytes that decoded decode too (`McapFile.check` skips rclpy's deserialiser for them).
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from operator import itemgetter

# bytes of each primitive in CDR (its alignment too)
PRIMITIVE_SIZE = {"bool": 1, "byte": 1, "char": 1, "int8": 1, "uint8": 1, "int16": 2, "uint16": 2, "int32": 4,
                  "uint32": 4, "float32": 4, "int64": 8, "uint64": 8, "float64": 8}
ENCAPSULATION = 4  # CDR alignment counts from the end of the encapsulation header

# walk plan operations (`Layouts._plan`); a boolean is a primitive whose bytes are decisive
_PRIM, _STRING, _PRIM_ARRAY, _PRIM_SEQ, _STRING_SEQ, _ITEMS_ARRAY, _ITEMS_SEQ, _BOOL = range(8)
_U32 = struct.Struct("<I")


class Layout:
    """One shape of one type: its length fields (offset, the 4 bytes there), padding and decisive spans."""

    __slots__ = ("lengths", "padding", "decisive", "end", "size", "_probe", "_expected", "_zero")

    def __init__(self, size: int) -> None:
        self.size = size  # the message's bytes, trailing ones included
        self.lengths: list[tuple[int, bytes]] = []
        self.padding: list[tuple[int, int]] = []
        self.decisive: list[tuple[int, int]] = [(0, ENCAPSULATION)]
        self.end = ENCAPSULATION
        self._probe: Callable[[bytes], tuple] | None = None
        self._expected: tuple = ()
        self._zero: Callable[[bytes], bytes] | None = None  # `zero_padding`, built at its first use

    def fits(self, data: bytes) -> bool:
        """Whether `data` has this shape: the same size and the same bytes in every length field."""
        if len(data) != self.size:
            return False
        probe = self._probe
        if probe is None:  # built at the first use, after the walk: one call takes every length field
            fields = [slice(at, at + 4) for at, _ in self.lengths] + [slice(0, 0)] * 2  # always a tuple
            probe = self._probe = itemgetter(*fields)
            self._expected = tuple(v for _, v in self.lengths) + (b"", b"")
        return probe(data) == self._expected

    def decisive_bytes(self, data: bytes) -> bytes:
        """The bytes of `data` decoding depends on (module doc), trailing bytes included."""
        return b"".join([data[a:b] for a, b in self.decisive]) + data[self.end:]

    def zero_padding(self, data: bytes) -> bytes:
        """`data` (of this shape: `fits`) with its alignment padding and trailing bytes zero."""
        zero = self._zero
        if zero is None:
            zero = self._zero = self._zeroing()
        return zero(data)

    def _zeroing(self) -> Callable[[bytes], bytes]:
        """`zero_padding` as two native calls: the spans between the padding taken by one `itemgetter`, and
        packed back by one `Struct` whose format puts pad bytes (zero) where the padding and the trailing bytes
        were (a deterministic bag's every message passes here: a slice assignment per span cost twice as much)."""
        keep: list[slice] = []
        fmt = ["<"]
        at = 0
        for a, b in sorted(self.padding) + [(self.end, self.size)]:
            if a > at:
                keep.append(slice(at, a))
                fmt.append(f"{a - at}s")
            if b > max(a, at):
                fmt.append(f"{b - max(a, at)}x")
            at = max(at, b)
        take = itemgetter(*keep, slice(0, 0))  # one more, empty: always a tuple
        pack = struct.Struct("".join(fmt) + "0s").pack
        return lambda data: pack(*take(data))


class Layouts:
    """`layout(type_name, data)`: the `Layout` of CDR bytes, or None when they cannot be walked
    (another encapsulation than little-endian CDR, a type the typestore lacks, a message cut short)."""

    MAX_SHAPES = 8  # per type: the shapes kept (a topic whose strings vary keeps walking, as before)

    def __init__(self, fielddefs, nodetype) -> None:
        self._fielddefs = fielddefs  # a rosbags typestore's `fielddefs`
        self._nodetype = nodetype
        self._plans: dict[str, list[tuple]] = {}
        self._known: dict[str, list[Layout]] = {}

    def layout(self, type_name: str, data: bytes) -> Layout | None:
        if len(data) < ENCAPSULATION or data[1] != 1:  # CDR_LE only
            return None
        known = self._known.get(type_name)
        if known is not None:
            for lay in known:
                if lay.fits(data):
                    return lay
        try:
            plan = self._plans.get(type_name)
            if plan is None:
                plan = self._plans[type_name] = self._plan(type_name)
            lay = Layout(len(data))
            lay.end = _walk(data, ENCAPSULATION, plan, lay)
        except (KeyError, IndexError, struct.error):
            return None
        if lay.end > len(data):
            return None
        if known is None:
            known = self._known[type_name] = []
        if len(known) >= self.MAX_SHAPES:
            known.pop(0)
        known.append(lay)
        return lay

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
            name = detail[0]
            return [(_STRING,)] if name == "string" else [(_BOOL,)] if name == "bool" else [(_PRIM, PRIMITIVE_SIZE[name])]
        if kind == nt.NAME:
            return self._plan(detail)
        element, count = detail
        ekind, edetail = element
        if ekind == nt.BASE and edetail[0] in PRIMITIVE_SIZE:  # booleans: their bytes decisive
            size, decisive = PRIMITIVE_SIZE[edetail[0]], edetail[0] == "bool"
            return [(_PRIM_SEQ, size, decisive)] if kind == nt.SEQUENCE else [(_PRIM_ARRAY, size, count, decisive)]
        if kind == nt.SEQUENCE and ekind == nt.BASE and edetail[0] == "string":
            return [(_STRING_SEQ,)]
        items = self._node(element)
        return [(_ITEMS_SEQ, items)] if kind == nt.SEQUENCE else [(_ITEMS_ARRAY, items, count)]


def _align(data: bytes, pos: int, size: int, lay: Layout) -> int:
    """The next multiple of `size` from `pos` (counted after the encapsulation), its gap noted as padding."""
    aligned = ENCAPSULATION + (pos - ENCAPSULATION + size - 1) // size * size
    if aligned != pos:
        if aligned > len(data):
            raise IndexError(aligned)
        lay.padding.append((pos, aligned))
    return aligned


def _length(data: bytes, pos: int, lay: Layout) -> int:
    """The 4-byte length at `pos` (aligned), noted as a length field and as decisive."""
    value = data[pos:pos + 4]
    n = _U32.unpack(value)[0]  # struct.error when cut short
    lay.lengths.append((pos, value))
    lay.decisive.append((pos, pos + 4))
    return n


def _string(data: bytes, pos: int, lay: Layout) -> int:
    pos = _align(data, pos, 4, lay)
    n = _length(data, pos, lay)
    lay.decisive.append((pos + 4, pos + 4 + n))
    return pos + 4 + n


def _walk(data: bytes, pos: int, plan: list[tuple], lay: Layout) -> int:
    """Note the layout of one message (or array item) laid out by `plan` into `lay`; returns where it ends."""
    for op in plan:
        code = op[0]
        if code == _PRIM:
            pos = _align(data, pos, op[1], lay) + op[1]
        elif code == _BOOL:
            lay.decisive.append((pos, pos + 1))
            pos += 1
        elif code == _STRING:
            pos = _string(data, pos, lay)
        elif code == _PRIM_SEQ or code == _PRIM_ARRAY:
            if code == _PRIM_SEQ:
                pos = _align(data, pos, 4, lay)
                n = _length(data, pos, lay)
                pos += 4
            else:
                n = op[2]
            if n:
                start = _align(data, pos, op[1], lay)
                pos = start + op[1] * n
                if op[-1]:
                    lay.decisive.append((start, pos))
        elif code == _STRING_SEQ:
            pos = _align(data, pos, 4, lay)
            n = _length(data, pos, lay)
            pos += 4
            for _ in range(n):
                if pos > len(data):
                    raise IndexError(pos)
                pos = _string(data, pos, lay)
        else:
            if code == _ITEMS_ARRAY:
                n = op[2]
            else:
                pos = _align(data, pos, 4, lay)
                n = _length(data, pos, lay)
                pos += 4
            for _ in range(n):
                if pos > len(data):  # a length no message of this size can hold: not walked item by item
                    raise IndexError(pos)
                pos = _walk(data, pos, op[1], lay)
    return pos
