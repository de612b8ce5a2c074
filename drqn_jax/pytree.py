"""Frozen dataclasses as JAX pytrees, and parameter fields with allowed ranges. Unflattening
bypasses ``__init__``, so JAX rebuilds objects from tracers, ``None`` or ``in_axes`` integers
without the validation that guards user construction. Switch fields (``choices=``) take names and
store ``int`` codes, so a switch can be swept under ``vmap`` like any number."""

import dataclasses
from collections.abc import Sequence
from typing import Any, TypeVar

import jax
import jax.numpy as jnp
import numpy as np

T = TypeVar("T")


def pytree_dataclass(cls: type[T] | None = None, *, meta_fields: Sequence[str] = ()) -> Any:
    """``cls`` as a frozen dataclass registered as a pytree; ``meta_fields`` are static
    (part of the tree structure), every other field a child."""

    def wrap(cls: type[T]) -> type[T]:
        cls = dataclasses.dataclass(frozen=True)(cls)
        names = tuple(f.name for f in dataclasses.fields(cls))
        data = tuple(n for n in names if n not in meta_fields)
        meta = tuple(n for n in names if n in meta_fields)
        keys = tuple(jax.tree_util.GetAttrKey(n) for n in data)

        def flatten_with_keys(obj):
            children = tuple((k, getattr(obj, n)) for k, n in zip(keys, data, strict=True))
            return children, tuple(getattr(obj, n) for n in meta)

        def unflatten(aux, children):
            obj = object.__new__(cls)
            for n, v in zip((*data, *meta), (*children, *aux), strict=True):
                object.__setattr__(obj, n, v)
            return obj

        jax.tree_util.register_pytree_with_keys(cls, flatten_with_keys, unflatten)
        cls.replace = lambda self, **kw: dataclasses.replace(self, **kw)  # type: ignore[attr-defined]
        return cls

    return wrap if cls is None else wrap(cls)


def param(
    default: Any,
    *,
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
    high_open: bool = False,
    choices: Sequence[str] | None = None,
    doc: str = "",
) -> Any:
    """A dataclass field allowed in ``[low, high]`` (ends optionally open), or a switch
    over ``choices`` stored as the name's index."""
    choices = None if choices is None else tuple(choices)
    meta = {"low": low, "high": high, "low_open": low_open, "high_open": high_open, "doc": doc}
    meta["choices"] = choices
    if choices is not None and isinstance(default, str):
        default = choices.index(default)
    return dataclasses.field(default=default, metadata=meta)


def is_concrete(value: Any) -> bool:
    return not any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(value))


def _allowed(meta: dict) -> str:
    low, high = meta["low"], meta["high"]
    lo = "" if low is None else f"{low} {'<' if meta['low_open'] else '<='} "
    hi = "" if high is None else f" {'<' if meta['high_open'] else '<='} {high}"
    return f"{lo}value{hi}".strip()


def validate(obj: Any) -> None:
    """Check every concrete field against its :func:`param` range (else a ValueError naming
    ``Class.field = value``) and store it as float32 (int32 for switches and integer fields), so
    eager arithmetic is ``jit``'s; from ``__post_init__`` only (it sets frozen fields)."""
    cls_name = type(obj).__name__
    for f in dataclasses.fields(obj):
        meta = f.metadata
        if "low" not in meta:
            continue
        value = getattr(obj, f.name)
        if not is_concrete(value):
            continue
        where = f"{cls_name}.{f.name} = {value!r}"
        choices = meta["choices"]
        if choices is not None:
            if isinstance(value, str):
                value = choices.index(value) if value in choices else -1
            arr = np.asarray(value)
            if not np.issubdtype(arr.dtype, np.integer) or np.any(
                (arr < 0) | (arr >= len(choices))
            ):
                raise ValueError(f"{where}: must be one of {', '.join(map(repr, choices))}")
            object.__setattr__(obj, f.name, arr.astype(np.int32))
            continue
        try:
            arr = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"{where}: must be a number ({_allowed(meta)})") from None
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{where}: must be finite ({_allowed(meta)})")
        low, high = meta["low"], meta["high"]
        bad = np.zeros(arr.shape, bool)
        if low is not None:
            bad |= (arr <= low) if meta["low_open"] else (arr < low)
        if high is not None:
            bad |= (arr >= high) if meta["high_open"] else (arr > high)
        if np.any(bad):
            raise ValueError(f"{where}: out of range, allowed {_allowed(meta)}")
        integer = isinstance(f.default, int) and not isinstance(f.default, bool)
        if integer and np.any(arr != np.round(arr)):
            raise ValueError(f"{where}: must be an integer ({_allowed(meta)})")
        object.__setattr__(obj, f.name, arr.astype(np.int32 if integer else np.float32))


def show_value(value: Any) -> str:
    """A concrete scalar as its shortest exact decimal (float32 0.4 -> ``0.4``), else repr."""
    arr = np.asarray(value)
    if arr.ndim == 0 and np.issubdtype(arr.dtype, np.floating):
        return np.format_float_positional(arr[()], unique=True, trim="-")
    if arr.ndim == 0 and np.issubdtype(arr.dtype, np.integer):
        return str(arr.item())
    return repr(value)


def tree_where(cond: jax.Array, a: Any, b: Any) -> Any:
    """Leaf-wise ``where(cond, a, b)``, ``cond`` (N,) broadcast over trailing axes."""

    def pick(x, y):
        return jnp.where(cond.reshape(cond.shape + (1,) * (x.ndim - cond.ndim)), x, y)

    return jax.tree.map(pick, a, b)


def check_counts(obj: Any, names: Sequence[str], *, low: int = 1) -> None:
    """Raise unless each field in ``names`` is an integer (not a bool) ``>= low``."""
    for name in names:
        value = getattr(obj, name)
        if not isinstance(value, int) or isinstance(value, bool) or value < low:
            raise ValueError(
                f"{type(obj).__name__}.{name} = {value!r}: must be an integer >= {low}"
            )


def check_order(obj: Any, lower: str, upper: str) -> None:
    """Raise unless ``obj.lower <= obj.upper`` for concrete values."""
    a, b = getattr(obj, lower), getattr(obj, upper)
    if is_concrete((a, b)) and not np.all(np.asarray(a) <= np.asarray(b)):
        name = type(obj).__name__
        raise ValueError(
            f"{name}.{lower} = {show_value(a)} and {name}.{upper} = {show_value(b)}: "
            f"must satisfy {lower} <= {upper}"
        )


def check_sums_to_one(obj: Any, names: Sequence[str], *, tol: float = 1e-6) -> None:
    """Raise unless the concrete fields ``names`` of ``obj`` sum to 1 (within ``tol``)."""
    values = [getattr(obj, n) for n in names]
    if not all(is_concrete(v) for v in values):
        return
    total = np.sum([np.asarray(v, dtype=np.float64) for v in values], axis=0)
    if not np.all(np.abs(total - 1.0) <= tol):
        parts = " + ".join(f"{n} ({show_value(getattr(obj, n))})" for n in names)
        raise ValueError(
            f"{type(obj).__name__}: {parts} = {float(np.max(total)):.6g}, must sum to 1"
        )
