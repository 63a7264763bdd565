"""The effect catalogue's mapping: effects registered for the process, and effects a user brings for one diagnosis.

The search looks effects up by name (``EFFECTS[name]``) in many places. A user's candidates
(:func:`~cosim.diagnose.user_candidates.candidate`) belong to the one diagnosis they were given to, and were once
put into the process-wide dict for its duration: two diagnoses in threads of one process (Dask's threaded
scheduler, a thread pool) then saw each other's candidates, and the one that brought a shared candidate second
left it out of its own search (it was in the catalogue already). Here they live in a context variable
(:mod:`contextvars`): each thread sees its own, and so does each asyncio task (it runs in a copy of its
context).

Examples
--------
>>> catalogue = Catalogue()
>>> catalogue["a"] = 1
>>> with catalogue.brought({"b": 2}):
...     sorted(catalogue), catalogue["b"]
(['a', 'b'], 2)
>>> "b" in catalogue
False
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, MutableMapping
from contextlib import contextmanager
from contextvars import ContextVar
from types import MappingProxyType
from typing import Generic, TypeVar

V = TypeVar("V")
_NONE: Mapping = MappingProxyType({})  # (what a context that brought nothing sees)


class Catalogue(MutableMapping[str, V], Generic[V]):
    """Name -> effect: the process's registered entries, with the current context's brought ones over them."""

    def __init__(self) -> None:
        self._registered: dict[str, V] = {}
        self._brought: ContextVar[Mapping[str, V]] = ContextVar(f"brought_{id(self)}", default=_NONE)

    def __getitem__(self, name: str) -> V:
        brought = self._brought.get()
        return brought[name] if name in brought else self._registered[name]

    def __iter__(self) -> Iterator[str]:
        brought = self._brought.get()
        yield from self._registered
        yield from (name for name in brought if name not in self._registered)

    def __len__(self) -> int:
        return len(set(self._registered) | set(self._brought.get()))

    def __setitem__(self, name: str, value: V) -> None:
        self._registered[name] = value

    def __delitem__(self, name: str) -> None:
        del self._registered[name]

    @contextmanager
    def brought(self, entries: Mapping[str, V]) -> Iterator[None]:
        """`entries` in the catalogue for the current context (thread, task) only, until the block ends."""
        token = self._brought.set({**self._brought.get(), **entries})
        try:
            yield
        finally:
            self._brought.reset(token)
