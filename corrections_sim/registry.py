"""Named plug-ins: one registry per kind (learners, simulated users, features).

A :class:`Registry` is a read-only mapping from a name to what was registered under it, in
registration order (the order figures and tables list them). Registering is one call or one
decorator; looking up an unknown name fails at once with a one-line message that lists the
known names, so a typo never falls through to a default::

    from corrections_sim.learning.base import LEARNERS, register_learner

    @register_learner("MINE")
    class Mine(Learner): ...

    LEARNERS["MINE"]    # the class
    LEARNERS["MIEN"]    # UnknownName: unknown learner 'MIEN': known are PP, KF, …, MINE
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator, Mapping
from typing import Generic, TypeVar

T = TypeVar("T")

#: What a name may look like: it becomes a file name (``<learner>-<run>.json``) and a CSV cell.
NAME_PATTERN = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_-]*")


class UnknownName(KeyError, ValueError):
    """A name that is not registered. Both a ``KeyError`` (mapping lookups) and a
    ``ValueError`` (bad input), with a one-line message."""

    def __str__(self) -> str:
        return str(self.args[0])


class Registry(Mapping[str, T], Generic[T]):
    """Name -> plug-in, in registration order.

    Args:
        kind: what it holds, singular ("learner"), for messages.
        check: what a registered item must be: returns None for a good item, else what is
            wrong with it ("is not a User subclass"), refused with a ``TypeError``.
        base: the class every item subclasses (checked, when ``check`` is not given).
    """

    def __init__(
        self,
        kind: str,
        check: Callable[[object], str | None] | None = None,
        *,
        base: type | None = None,
    ) -> None:
        self.kind = kind
        self.base = base
        self._check = check if check is not None or base is None else self.subclass_of(base)
        self._items: dict[str, T] = {}
        self._retired: dict[str, str] = {}

    def register(self, name: str, item: T, *, replace: bool = False) -> T:
        """Add ``item`` under ``name``; returns ``item``.

        Raises:
            ValueError: a malformed name, or one already taken (unless ``replace``).
            TypeError: an item the registry's ``check`` refuses.
        """
        problem = self._check(item) if self._check is not None else None
        if problem is not None:
            raise TypeError(f"{self.kind} {name!r}: {item!r} {problem}")
        if not isinstance(name, str) or not NAME_PATTERN.fullmatch(name):
            raise ValueError(
                f"{self.kind} name {name!r}: letters, digits, '_' and '-' only, not first '-'"
            )
        if name in self._items and not replace:
            raise ValueError(f"{self.kind} {name!r} is already registered")
        self._items[name] = item
        self._retired.pop(name, None)
        return item

    def retire(self, name: str, why: str) -> None:
        """Say that ``name`` left the registry and why: looking it up then fails with that
        reason instead of "unknown" (a study file, a recorded summary or a command line that
        names it). A plug-in may register the name again."""
        if name in self._items:
            raise ValueError(f"{self.kind} {name!r} is registered: unregister it first")
        self._retired[name] = why

    def decorator(self, name: str, *, replace: bool = False) -> Callable[[T], T]:
        """``@registry.decorator(name)``: register the decorated object under ``name``."""

        def add(item: T) -> T:
            return self.register(name, item, replace=replace)

        return add

    @staticmethod
    def subclass_of(base: type) -> Callable[[object], str | None]:
        """A ``check`` that accepts subclasses of ``base`` only."""

        def check(item: object) -> str | None:
            ok = isinstance(item, type) and issubclass(item, base)
            return None if ok else f"is not a {base.__name__} subclass"

        return check

    def unregister(self, name: str) -> None:
        """Remove ``name`` (tests and interactive sessions; a study never needs it)."""
        self[name]  # refuses unknown names like a lookup
        del self._items[name]

    def retired(self, name: object) -> str | None:
        """Why ``name`` left the registry, or None (it never did, or was registered again)."""
        return self._retired.get(name) if isinstance(name, str) else None

    def check(self, names) -> tuple[str, ...]:
        """``names`` as a tuple, refused unless they are distinct registered names."""
        names = tuple(names)
        for name in names:
            self[name]
        if not names or len(set(names)) != len(names):
            raise ValueError(f"{self.kind}s: {list(names)} must be distinct and not empty")
        return names

    def __getitem__(self, name: str) -> T:
        try:
            return self._items[name]
        except (KeyError, TypeError):
            known = ", ".join(self._items) or "none"
            why = self.retired(name)
            if why is not None:
                raise UnknownName(
                    f"{self.kind} {name!r} left the registry: {why}; known are {known}"
                ) from None
            raise UnknownName(f"unknown {self.kind} {name!r}: known are {known}") from None

    def __iter__(self) -> Iterator[str]:
        return iter(self._items)

    def __len__(self) -> int:
        return len(self._items)

    def __repr__(self) -> str:
        return f"Registry({self.kind!r}, {list(self._items)})"
