"""Immutable dataclasses that are JAX pytrees.

`pytree_dataclass(meta=(...))` turns a class into a frozen dataclass whose fields named in
`meta` are static (hashable Python data that becomes part of the tree structure, so it
keys JAX's compilation cache) and whose other fields are array leaves (numbers one may
differentiate). Unflattening bypasses ``__init__``/``__post_init__``, so validation in
``__post_init__`` runs only when users build objects, never on tracers or placeholder
leaves that JAX transformations pass through.
"""

from __future__ import annotations

import dataclasses

import jax


class _Label:
    """Carries informational static data (names, file paths) through a tree structure
    without keying JAX's compile cache: all labels compare equal."""

    __slots__ = ("value",)

    def __init__(self, value):
        self.value = value

    def __eq__(self, other):
        return isinstance(other, _Label)

    def __hash__(self):
        return 0


def pytree_dataclass(cls=None, *, meta: tuple[str, ...] = (), labels: tuple[str, ...] = ()):
    """``meta``: static fields that key compilation; ``labels``: static fields that
    don't (e.g. a model's name), so objects differing only in labels share compiled code."""
    meta = tuple(meta) + tuple(labels)

    def wrap(cls):
        cls = dataclasses.dataclass(frozen=True, eq=False)(cls)
        names = [f.name for f in dataclasses.fields(cls)]
        data_names = tuple(n for n in names if n not in meta)
        meta_names = tuple(n for n in names if n in meta)

        def aux_of(obj):
            return tuple(_Label(getattr(obj, n)) if n in labels else getattr(obj, n) for n in meta_names)

        def flatten_with_keys(obj):
            children = [(jax.tree_util.GetAttrKey(n), getattr(obj, n)) for n in data_names]
            return children, aux_of(obj)

        def flatten(obj):
            return [getattr(obj, n) for n in data_names], aux_of(obj)

        def unflatten(aux, children):
            obj = object.__new__(cls)
            for n, c in zip(data_names, children):
                object.__setattr__(obj, n, c)
            for n, a in zip(meta_names, aux):
                object.__setattr__(obj, n, a.value if isinstance(a, _Label) else a)
            return obj

        jax.tree_util.register_pytree_with_keys(cls, flatten_with_keys, unflatten, flatten)
        cls._data_fields = data_names
        cls._meta_fields = meta_names
        return cls

    return wrap if cls is None else wrap(cls)


def replace(obj, **changes):
    """Copy of a pytree dataclass with some fields changed (no validation re-run)."""
    new = object.__new__(type(obj))
    for f in dataclasses.fields(obj):
        object.__setattr__(new, f.name, changes.get(f.name, getattr(obj, f.name)))
    return new


def is_concrete(*xs) -> bool:
    """True when every argument is concrete data (not a JAX tracer)."""
    return not any(isinstance(x, jax.core.Tracer) for x in jax.tree_util.tree_leaves(xs))
