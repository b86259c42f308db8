"""Memo caches of results that are costly to compute again: a deterministic function's result kept
by the content of its inputs (``ContentMemo``), and the last result of a function of the same input
objects (``LastCall``). Both are thread-safe; neither changes a result, only whether it is computed.
"""
from __future__ import annotations

import threading
from collections import OrderedDict
from typing import Callable

import jax

from jaxflex import trees


class ContentMemo:
    """Results (pytrees of arrays) kept by a digest of the inputs' content (``trees.content_key``),
    the oldest forgotten beyond ``max_bytes`` in all; a result larger than a quarter of that is not
    kept."""

    def __init__(self, max_bytes: int):
        self.max_bytes = int(max_bytes)
        self._items: OrderedDict = OrderedDict()       # key -> (value, size)
        self._lock = threading.Lock()

    def get(self, key: bytes):
        """The result kept under ``key``, or None."""
        with self._lock:
            hit = self._items.get(key)
            if hit is None:
                return None
            self._items.move_to_end(key)
            return hit[0]

    def put(self, key: bytes, value) -> None:
        size = sum(v.nbytes for v in jax.tree_util.tree_leaves(value))      # no copy to the host
        if size > self.max_bytes // 4:
            return
        with self._lock:
            self._items[key] = (value, size)
            while sum(s for _, s in self._items.values()) > self.max_bytes:
                self._items.popitem(last=False)

    def __call__(self, fn: Callable, *inputs):
        """``fn(*inputs)``, or the result kept for inputs of the same content."""
        key = trees.content_key(*inputs)
        out = self.get(key)
        if out is None:
            out = fn(*inputs)
            self.put(key, out)
        return out

    def clear(self) -> None:
        with self._lock:
            self._items.clear()


class LastCall:
    """The result of ``fn(*inputs)`` for the last inputs, returned again while the same objects
    (by identity) come back: an optimizer calls with the same data at every step."""

    def __init__(self):
        self._last: list = []
        self._lock = threading.Lock()

    def __call__(self, fn: Callable, *inputs):
        with self._lock:
            if self._last and len(self._last[0]) == len(inputs) and all(a is b for a, b in zip(self._last[0], inputs)):
                return self._last[1]
            out = fn(*inputs)
            self._last[:] = [inputs, out]
            return out
