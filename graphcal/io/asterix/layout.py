"""Byte layouts of ASTERIX records, compiled from ``libasterix``'s specifications.

The fast decoder (:mod:`graphcal.io.asterix.decode`) walks a record's FSPEC
with plain integer arithmetic: for every item of the user application profile
(UAP) it needs how many bytes the item takes, which this module derives once
from the specification classes of ``libasterix`` (``asterix.generated``), so
that both agree on every item of every edition decoded:

- an element or group item has a fixed size (an ``int``, bytes);
- an extended item is a chain of parts, each ending in an FX bit
  (:class:`ExtendedLayout`);
- a repetitive item is a repetition count then fixed-size elements, or
  elements each ending in an FX bit (:class:`RepetitiveLayout`);
- an explicit item starts with its own length byte (:data:`EXPLICIT`);
- a compound item has its own FSPEC and sub-items (:class:`CompoundLayout`).

It also locates a field (:func:`locate`): its bit offset inside its item, its
width, signedness and LSB, so that values are extracted with numpy over many
records at once and equal what ``libasterix`` gives (``signed(raw) * lsb``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from asterix import base

#: Marker of an explicit item (first byte: the item's length, itself included).
EXPLICIT = "explicit"


@dataclass(frozen=True)
class ExtendedLayout:
    """An extended item: parts of ``sizes[k]`` bytes; a part whose ``fx[k]`` is True
    ends in an FX bit (1: another part follows)."""

    sizes: tuple[int, ...]
    fx: tuple[bool, ...]


@dataclass(frozen=True)
class RepetitiveLayout:
    """A repetitive item: ``rep_bytes`` count bytes then ``count`` elements of
    ``element`` bytes; ``rep_bytes`` 0 means elements that each end in an FX bit."""

    rep_bytes: int
    element: int


@dataclass(frozen=True)
class CompoundLayout:
    """A compound item: an FSPEC of at most ``max_fspec`` bytes, then the sub-items
    flagged (``items[k]`` is ``None`` for a position without an item)."""

    max_fspec: int
    items: tuple[Any, ...]


#: What one item of a UAP takes: bytes, or one of the layouts above.
ItemLayout = int | ExtendedLayout | RepetitiveLayout | CompoundLayout | str


@dataclass(frozen=True)
class RecordLayout:
    """The UAP of a record, as the walker reads it.

    Attributes
    ----------
    names : tuple of str or None
        Item name (``"010"``, ...) at each FSPEC position; ``None`` for a spare
        position (flagging it makes the record invalid).
    items : tuple of ItemLayout or None
        Layout at each position (``None`` for a spare position).
    max_fspec : int
        Largest FSPEC [bytes].
    """

    names: tuple[str | None, ...]
    items: tuple[ItemLayout | None, ...]
    max_fspec: int

    def position(self, name: str) -> int:
        """FSPEC position (0-based) of item ``name``."""
        return self.names.index(name)


@dataclass(frozen=True)
class FieldLayout:
    """Where a field sits in its item and how its raw bits become a value.

    Attributes
    ----------
    item : str
        Item name.
    part : int
        Part of an extended item that holds the field (0 otherwise).
    bit_offset : int
        Bits from the start of the item to the field's first bit.
    bit_size : int
        Width [bits].
    signed : bool
        Two's complement.
    lsb : float or None
        Value of one count for a quantity, else ``None`` (raw integer or string).
    """

    item: str
    part: int
    bit_offset: int
    bit_size: int
    signed: bool
    lsb: float | None


class LayoutError(Exception):
    """A specification construct the fast decoder does not support."""


def _variation(non_spare: Any) -> Any:
    rule = non_spare.cv_rule
    if hasattr(rule, "cv_variation"):
        return rule.cv_variation
    return rule.cv_default_variation


def _bits(variation: Any) -> int:
    """Width of a fixed-size variation [bits]."""
    if issubclass(variation, base.Element | base.Group):
        return int(variation.cv_bit_size)
    raise LayoutError(f"{variation.__name__} has no fixed size")


def _item_layout(variation: Any) -> ItemLayout:
    if issubclass(variation, base.Element | base.Group):
        bits = _bits(variation)
        if bits % 8:
            raise LayoutError(f"{variation.__name__}: {bits} bits is not whole bytes")
        return bits // 8
    if issubclass(variation, base.Extended):
        sizes, fx = [], []
        for part in variation.cv_items_list:
            bits = sum(1 if entry is None else entry[1] for entry in part)
            if bits % 8:
                raise LayoutError(f"{variation.__name__}: a part of {bits} bits")
            sizes.append(bits // 8)
            fx.append(part[-1] is None)
        return ExtendedLayout(tuple(sizes), tuple(fx))
    if issubclass(variation, base.Repetitive):
        bits = _bits(variation.cv_variation)
        if variation.cv_rep_bytes is None:
            if (bits + 1) % 8:
                raise LayoutError(f"{variation.__name__}: FX elements of {bits} bits")
            return RepetitiveLayout(0, (bits + 1) // 8)
        if bits % 8:
            raise LayoutError(f"{variation.__name__}: elements of {bits} bits")
        return RepetitiveLayout(int(variation.cv_rep_bytes), bits // 8)
    if issubclass(variation, base.Explicit):
        return EXPLICIT
    if issubclass(variation, base.Compound):
        return CompoundLayout(
            int(variation.cv_fspec_max_bytes),
            tuple(None if nsp is None else _item_layout(_variation(nsp))
                  for nsp in variation.cv_items_list))
    raise LayoutError(f"unsupported variation {variation.__name__}")


def record_layout(spec: Any) -> RecordLayout:
    """The :class:`RecordLayout` of a ``libasterix`` category edition (``Cat_048_1_32``).

    Raises
    ------
    LayoutError
        A UAP with random field sequencing or an item whose size cannot be
        computed this way.
    """
    record = spec.cv_record
    names: list[str | None] = []
    items: list[ItemLayout | None] = []
    for entry in record.cv_items_list:
        if issubclass(entry, base.UapItem):
            names.append(entry.cv_non_spare.cv_name)
            items.append(_item_layout(_variation(entry.cv_non_spare)))
        elif issubclass(entry, base.UapItemSpare):
            names.append(None)
            items.append(None)
        else:
            raise LayoutError(f"{spec.__name__}: random field sequencing is not supported")
    return RecordLayout(tuple(names), tuple(items), int(record.cv_fspec_max_bytes))


def _content(variation: Any) -> tuple[bool, float | None]:
    """(signed, lsb) of an element's content (lsb ``None`` when not a quantity)."""
    rule = variation.cv_rule
    content = rule.cv_content if hasattr(rule, "cv_content") else rule.cv_default_content
    if issubclass(content, base.ContentQuantity):
        return issubclass(content.cv_signedness, base.Signed), float(content.cv_lsb)
    if issubclass(content, base.ContentInteger):
        return issubclass(content.cv_signedness, base.Signed), None
    return False, None


def locate(spec: Any, item: str, field: str | None = None) -> FieldLayout:
    """Where ``field`` of ``item`` sits (``field=None``: the item is one element).

    Parameters
    ----------
    spec : libasterix category edition
        E.g. ``asterix.generated.Cat_048_1_32``.
    item : str
        Item name, e.g. ``"040"``.
    field : str, optional
        Subfield of a group or extended item, e.g. ``"RHO"``.

    Raises
    ------
    LayoutError
        When the field is not a fixed element of that item.
    """
    variation = _variation(spec.cv_record.cv_items_dict[item])
    if field is None:
        if not issubclass(variation, base.Element):
            raise LayoutError(f"I{item} is not an element")
        return FieldLayout(item, 0, 0, int(variation.cv_bit_size), *_content(variation))
    if issubclass(variation, base.Group):
        parts = [list(variation.cv_items_list)]
    elif issubclass(variation, base.Extended):
        parts = [[entry for entry in part if entry is not None]
                 for part in variation.cv_items_list]
        parts = [part + [None] if original[-1] is None else part
                 for part, original in zip(parts, variation.cv_items_list, strict=True)]
    else:
        raise LayoutError(f"I{item} has no subfields")
    offset = 0
    for index, part in enumerate(parts):
        for entry in part:
            if entry is None:  # FX bit
                offset += 1
                continue
            kind, size = entry
            if issubclass(kind, base.Item) and kind.cv_non_spare.cv_name == field:
                sub = _variation(kind.cv_non_spare)
                if not issubclass(sub, base.Element):
                    raise LayoutError(f"I{item}/{field} is not an element")
                return FieldLayout(item, index, offset, int(size), *_content(sub))
            offset += size
    raise LayoutError(f"I{item} has no field {field}")
