"""Compare serialized messages as CDR defines them: to the end of the CDR data, padding aside.

rmw_fastrtps sizes the buffer of a type with strings inside sequences by an estimate (bytes
past the CDR data are undefined) and leaves padding bytes as its buffer held them (CDR leaves
them unspecified), so two serializations of equal messages may differ there and only there.
"""

from __future__ import annotations

from typing import Any


def cdr_end(data: bytes, cls: type) -> int:
    """The end of the CDR data in ``data`` (a serialized ``cls``)."""
    from rosbags.typesys import get_typestore, Stores
    store = get_typestore(Stores.ROS2_JAZZY)
    msgdef = store.get_msgdef(f'{cls.__module__.split(".")[0]}/msg/{cls.__name__}')
    _, pos = msgdef.deserialize_cdr_le(memoryview(data)[4:], 0, msgdef.cls, store)
    return 4 + pos


def padding(msg: Any) -> list[int]:
    """Byte positions of the CDR padding of ``msg`` (from the padding-marking encoder)."""
    from enbarr_core.recording import cdr
    cls = type(msg)
    encode, mark = cdr.encoder(cls), cdr.padding_marking_encoder(cls)
    if encode is None or mark is None:
        return []
    plain, marked = encode(msg), mark(msg)
    return [i for i in range(len(plain)) if plain[i] != marked[i]]


def zeroed(data: bytes, positions: list[int]) -> bytes:
    """``data`` with the bytes at ``positions`` set to zero."""
    out = bytearray(data)
    for i in positions:
        if i < len(out):
            out[i] = 0
    return bytes(out)


def same_cdr(ours: bytes, reference: bytes, msg: Any) -> bool:
    """Whether two serializations of ``msg``'s type agree on every byte that CDR defines."""
    cls = type(msg)
    end = cdr_end(reference, cls)
    pad = padding(msg)
    return cdr_end(ours, cls) == end and zeroed(ours[:end], pad) == zeroed(reference[:end], pad)
