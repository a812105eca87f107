"""Stage 1, the cloud: binary PLY elements whose list properties vary in length from record to record.

A binary record's size depends on its list counts, so where one record starts depends on every
record before it; when the lists are not all of one length (mixed triangles and quads, say) the
records are walked by one compiled loop (:func:`_walk_records`, numba) and the list items then
gathered with numpy. Imported only for such files; the common case, lists all of one length, is a
``numpy.frombuffer`` view in :mod:`planning.inputs.ply`.

The walk allocates 16 bytes per record, and only for the element whose list is gathered (the faces);
:mod:`planning.inputs.ply` has checked before that the declared records can fit in the file (and the
faces under ``max_faces``), so a header that claims billions of records allocates nothing. The items
are gathered a byte column at a time: about 8 bytes of indices per item besides the items themselves.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _walk_records(buf, start, count, kinds, sizes, count_sizes, big_endian, want):  # pragma: no cover
    """Walk ``count`` records from byte ``start``.

    ``kinds[j]`` is 0 for a scalar of ``sizes[j]`` bytes, 1 for a list with a ``count_sizes[j]``-byte
    unsigned count and items of ``sizes[j]`` bytes. Returns (end offset or -1 if a record runs past
    the end of ``buf``, records complete, byte offset of the first item of list ``want`` per record,
    item count of list ``want`` per record; both empty when ``want`` is -1).
    """
    kept = count if want >= 0 else 0
    item_at = np.zeros(kept, dtype=np.int64)
    n_items = np.zeros(kept, dtype=np.int64)
    pos = start
    n = buf.size
    for i in range(count):
        for j in range(kinds.size):
            if kinds[j] == 0:
                pos += sizes[j]
                continue
            cs = count_sizes[j]
            if pos + cs > n:
                return -1, i, item_at, n_items
            c = 0
            for b in range(cs):
                k = b if big_endian else cs - 1 - b
                c = c * 256 + buf[pos + k]
            pos += cs
            if j == want:
                item_at[i] = pos
                n_items[i] = c
            pos += c * sizes[j]
        if pos > n:
            return -1, i, item_at, n_items
    return pos, count, item_at, n_items


def walk_list_element(data: bytes, offset: int, count: int, props, endian: str, want: str | None):
    """Walk a binary element of ``count`` records from byte ``offset``.

    ``props`` are the element's properties as in :mod:`planning.inputs.ply` (``(name, type)`` for
    scalars, ``(name, count type, item type)`` for lists); ``want`` names the list to gather (None:
    only the end offset). Returns (end offset or -1 if the file ends inside a record, complete
    records, items of ``want`` concatenated as its item type, items per record). The caller has checked
    that ``count`` records of the smallest possible size fit in ``data`` after ``offset``.
    """
    buf = np.frombuffer(data, dtype=np.uint8)
    kinds = np.array([0 if len(p) == 2 else 1 for p in props], dtype=np.int64)
    sizes = np.array([np.dtype(p[-1]).itemsize for p in props], dtype=np.int64)
    count_sizes = np.array([np.dtype(p[1]).itemsize if len(p) == 3 else 0 for p in props],
                           dtype=np.int64)
    names = [p[0] for p in props]
    w = names.index(want) if want is not None else -1
    end, done, item_at, n_items = _walk_records(buf, int(offset), int(count), kinds, sizes,
                                                count_sizes, endian == ">", w)
    if w < 0 or end < 0:
        return int(end), int(done), None, None
    item = np.dtype(endian + props[w][2])
    first = np.cumsum(n_items) - n_items
    at = np.arange(int(n_items.sum()), dtype=np.int64)
    at -= np.repeat(first, n_items)                       # rank of each item in its list
    at *= item.itemsize
    at += np.repeat(item_at, n_items)                     # byte offset of each item
    raw = np.empty((at.size, item.itemsize), dtype=np.uint8)
    for k in range(item.itemsize):
        raw[:, k] = buf[at + k]
    return int(end), int(done), raw.view(item).reshape(-1), n_items
