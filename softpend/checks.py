"""Argument checks shared by the whole package."""

from __future__ import annotations

import math
from typing import Any, Callable, Collection, Optional, TypeVar

import numpy as np

T = TypeVar("T")


class NonFiniteError(ValueError):
    """A computed quantity that must stay finite (network weights, a training loss, a metric) became NaN or
    infinite; the message names the quantity and where it happened."""


#: Largest array memory [bytes] that one piece of work (a dataset, a set of evaluation trajectories) may plan for;
#: larger work is refused before it starts (:func:`check_work_size`).
MAX_WORK_BYTES = 4 * 2**30


def check_work_size(what: str, n_bytes: float, estimate: str) -> None:
    """``ValueError`` if ``n_bytes``, the estimated array memory of ``what``, exceeds :data:`MAX_WORK_BYTES`;
    the message shows the estimate and ``estimate``, how it was computed (e.g. ``"6000 steps x 80 bytes"``)."""
    if not n_bytes <= MAX_WORK_BYTES:  # also NaN
        raise ValueError(
            f"{what} would need about {n_bytes / 2**30:.3g} GiB of arrays ({estimate}), more than the "
            f"{MAX_WORK_BYTES / 2**30:g} GiB that one piece of work may use"
        )


def _real(value: Any) -> Optional[float]:
    """``value`` as a float if it is a finite real number (not a bool), else ``None``."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        return None
    try:
        number = float(value)
    except OverflowError:  # an integer beyond the float range
        return None
    return number if math.isfinite(number) else None


def _integer(value: Any) -> Optional[int]:
    """``value`` as an int if it is an integer (or a float with an integral value, not a bool), else ``None``."""
    if isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_)):
        return int(value)
    number = _real(value)
    return int(number) if number is not None and number.is_integer() else None


def _checked(name: str, number: Any, value: Any, ok: Callable[[Any], bool], what: str) -> Any:
    if number is None or not ok(number):
        raise ValueError(f"{name} must {what}, got {value!r}")
    return number


def finite(name: str, value: Any) -> float:
    """``value`` as a float if it is a finite number, else ``ValueError`` naming ``name``."""
    return _checked(name, _real(value), value, lambda n: True, "be finite")


def positive(name: str, value: Any) -> float:
    """``value`` as a float if it is a positive finite number, else ``ValueError`` naming ``name``."""
    return _checked(name, _real(value), value, lambda n: n > 0.0, "be positive and finite")


def optional_positive(name: str, value: Any) -> Optional[float]:
    """``None`` for ``None``, else ``value`` as a float if it is a positive finite number; ``ValueError`` otherwise."""
    if value is None:
        return None
    return _checked(name, _real(value), value, lambda n: n > 0, "be positive and finite or None")


def non_negative(name: str, value: Any) -> float:
    """``value`` as a float if it is a finite number >= 0, else ``ValueError`` naming ``name``."""
    return _checked(name, _real(value), value, lambda n: n >= 0.0, "be non-negative and finite")


def positive_int(name: str, value: Any) -> int:
    """``value`` as an int if it is an integer >= 1, else ``ValueError`` naming ``name``."""
    return _checked(name, _integer(value), value, lambda n: n >= 1, "be a positive integer")


def int_at_least(name: str, value: Any, low: int) -> int:
    """``value`` as an int if it is an integer >= ``low``, else ``ValueError`` naming ``name``."""
    return _checked(name, _integer(value), value, lambda n: n >= low, f"be an integer >= {low}")


def in_range(name: str, value: Any, low: float, high: float) -> float:
    """``value`` as a float if it is a finite number in ``[low, high]``, else ``ValueError`` naming the range."""
    return _checked(name, _real(value), value, lambda n: low <= n <= high, f"lie in [{low:g}, {high:g}]")


def in_unit_interval(name: str, value: Any, *, include_zero: bool = True, include_one: bool = True) -> float:
    """``value`` as a float if it lies in the unit interval, else ``ValueError`` naming ``name``."""

    def inside(n: float) -> bool:
        return (n >= 0.0 if include_zero else n > 0.0) and (n <= 1.0 if include_one else n < 1.0)

    interval = f"{'[' if include_zero else '('}0, 1{']' if include_one else ')'}"
    return float(_checked(name, _real(value), value, inside, f"lie in {interval}"))


def one_of(name: str, value: T, choices: Collection[Any]) -> T:
    """``value`` itself if it is one of ``choices``, else ``ValueError`` naming ``name`` and listing them."""
    try:
        known = value in choices
    except TypeError:  # an unhashable value tested against a set or dict
        known = False
    if not known:
        shown = list(choices) if isinstance(choices, (list, tuple)) else sorted(choices, key=repr)
        raise ValueError(f"{name} must be one of {shown}, got {value!r}")
    return value


def boolean(name: str, value: Any) -> bool:
    """``value`` if it is a ``bool`` (or a NumPy bool), else ``ValueError`` naming ``name``."""
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be a bool, got {value!r}")
    return bool(value)


def set_ints(obj: Any, names: str, low: int, prefix: str = "") -> None:
    """Check and store the int fields ``names`` (space-separated), each ``>= low``, of a (frozen) dataclass ``obj``."""
    for name in names.split():
        value, shown = getattr(obj, name), prefix + name
        object.__setattr__(obj, name, positive_int(shown, value) if low == 1 else int_at_least(shown, value, low))


def seed_tuple(name: str, value: Any, non_empty: bool = False) -> tuple[int, ...]:
    """``value`` as a tuple of seeds (ints >= 0; at least one if ``non_empty``), else ``ValueError`` naming ``name``."""
    try:
        seeds = tuple(int_at_least(name, s, 0) for s in value)
    except TypeError:
        raise ValueError(f"{name} must be a tuple of integers >= 0, got {value!r}") from None
    if non_empty and not seeds:
        raise ValueError(f"{name} must not be empty")
    return seeds


def positive_ints(name: str, value: Any) -> tuple[int, ...]:
    """``value`` as a non-empty tuple of positive ints, else ``ValueError`` naming ``name``."""
    try:
        widths = tuple(positive_int(name, w) for w in value)
    except (TypeError, ValueError):
        widths = ()
    if not widths:
        raise ValueError(f"{name} must be a non-empty tuple of positive integers, got {value!r}")
    return widths


def instance_of(name: str, value: Any, cls: type) -> Any:
    """``value`` if it is a ``cls``, else ``ValueError`` naming ``name``."""
    if not isinstance(value, cls):
        raise ValueError(f"{name} must be a {cls.__name__}, got {type(value).__name__}")
    return value


def _assigned_names(source: str) -> set[str]:
    """Names bound by top-level assignments in Python ``source`` (empty if it does not parse)."""
    import ast

    try:
        body = ast.parse(source).body
    except SyntaxError:
        return set()
    targets = [t for n in body if isinstance(n, ast.Assign) for t in n.targets]
    targets += [n.target for n in body if isinstance(n, ast.AnnAssign)]
    return {n.id for target in targets for n in ast.walk(target) if isinstance(n, ast.Name)}


def check_notebook_parameters() -> None:
    """In a notebook executed by papermill: ``ValueError`` if a parameter was given that the notebook's
    ``parameters`` cell does not define."""
    from IPython import get_ipython

    history = list(shell.user_ns.get("In", [])) if (shell := get_ipython()) is not None else []
    injected = [
        i for i, text in enumerate(history) if isinstance(text, str) and text.lstrip().startswith("# Parameters")
    ]
    if injected and injected[-1] >= 1:
        declared = _assigned_names(history[injected[-1] - 1])
        if unknown := sorted(_assigned_names(history[injected[-1]]) - declared):
            raise ValueError(
                f"parameter(s) {unknown} are not defined in this notebook's parameters cell (it defines {sorted(declared)})"
            )
