"""Work shared between the stages of one calibration.

The initial values, the factors, the Cramér-Rao bound and the model checks of one
calibration each need the same derived arrays: every radar's plots as SI arrays, the
ADS-B reports grouped by aircraft, the plots aligned with ADS-B.  Inside
:func:`sharing` (a context manager, or a decorator of the function that runs the
stages), :func:`remember` computes such a value once per key and hands the same object
to every later caller; outside, it simply computes it, so that a function called on its
own behaves as before.

A value is filed under a key and the objects it derives from (the tables, the site),
by identity, and dropped as soon as one of those objects is freed (it is referenced
weakly), so that a loop over many datasets (time windows) does not accumulate them.
This is sound because nothing modifies a table in place during a calibration; a table
changed between two calibrations is seen afresh, since every block starts empty.  A
value handed out may be shared: callers treat it as read-only.
"""

from __future__ import annotations

import functools
import weakref
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from typing import Any, ParamSpec, TypeVar

T = TypeVar("T")
P = ParamSpec("P")

#: The store of the active block: key -> (references to the objects the value derives
#: from, value).
_STORE: ContextVar[dict[tuple, tuple[tuple[Callable[[], object], ...], Any]] | None] = (
    ContextVar("graphcal_memo", default=None)
)


@contextmanager
def sharing() -> Iterator[None]:
    """Share :func:`remember`'s values within the block; a nested block joins the outer one."""
    if _STORE.get() is not None:
        yield
        return
    token = _STORE.set({})
    try:
        yield
    finally:
        _STORE.reset(token)


def shared(function: Callable[P, T]) -> Callable[P, T]:
    """Decorator: run ``function`` inside :func:`sharing`."""

    @functools.wraps(function)
    def wrapper(*args: P.args, **kwargs: P.kwargs) -> T:
        with sharing():
            return function(*args, **kwargs)

    return wrapper


def remember(name: tuple, sources: tuple[object, ...], compute: Callable[[], T]) -> T:
    """``compute()``, once per ``(name, sources)`` while a :func:`sharing` block is active.

    Parameters
    ----------
    name : tuple
        What the value is, with its hashable parameters, e.g. ``("plot_arrays", "NORD")``.
    sources : tuple of object
        The objects the value is computed from, compared by identity (tables, sites).
    compute : callable
        Computes the value.

    Returns
    -------
    object
        The value; inside a block, the same object for every call with the same key.
    """
    store = _STORE.get()
    if store is None:
        return compute()
    key = (name, tuple(id(s) for s in sources))
    hit = store.get(key)
    if hit is not None and all(ref() is s for ref, s in zip(hit[0], sources, strict=True)):
        return hit[1]
    value = compute()
    store[key] = (tuple(_reference(s, store, key) for s in sources), value)
    return value


def _reference(source: object, store: dict, key: tuple) -> Callable[[], object]:
    """A weak reference to ``source`` that drops ``store[key]`` when ``source`` is freed
    (a strong one for objects that take no weak reference)."""
    try:
        return weakref.ref(source, lambda _: store.pop(key, None))
    except TypeError:
        return lambda: source


def active() -> bool:
    """Whether a :func:`sharing` block is active."""
    return _STORE.get() is not None


__all__ = ["active", "remember", "shared", "sharing"]
