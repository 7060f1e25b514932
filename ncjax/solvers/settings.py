"""How the solvers' and the pipeline's configurations are made: frozen dataclasses that are also JAX pytrees.

Each stage's configuration (:class:`~ncjax.solvers.ransac.RansacConfig`,
:class:`~ncjax.pipeline.config.CornerConfig`, ...) names its static fields: those
set shapes, loop lengths or which code runs, and are part of the pytree's structure, so that changing one compiles
the pipeline anew. Its other fields (thresholds and weights) are the pytree's leaves: a jitted function that takes
the configuration as an argument traces them, and another threshold reuses the compiled program. The pipeline's
values are given for the 1024 x 512 reference panorama and scaled to the camera's size (:func:`scaled`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, TypeVar

import jax
from jaxtyping import ArrayLike, Float

T = TypeVar("T")


def settings(*, static: tuple[str, ...]) -> Callable[[type[T]], type[T]]:
    """Make ``cls`` a frozen dataclass and a pytree whose leaves are its fields outside ``static``.

    A pytree rebuilt inside ``jax.jit`` holds tracers, so it is rebuilt without ``__init__`` (no validation:
    the values were validated when the configuration was made).
    """

    def register(cls: type[T]) -> type[T]:
        cls = dataclasses.dataclass(frozen=True)(cls)
        names = [field.name for field in dataclasses.fields(cls)]
        unknown = set(static) - set(names)
        if unknown:
            raise TypeError(f"{cls.__name__}: static fields {sorted(unknown)} are not fields")
        traced = tuple(name for name in names if name not in static)

        def flatten(config):
            children = [(jax.tree_util.GetAttrKey(name), getattr(config, name)) for name in traced]
            return children, tuple(getattr(config, name) for name in static)

        def unflatten(static_values, traced_values):
            config = object.__new__(cls)
            for name, value in (*zip(static, static_values, strict=True), *zip(traced, traced_values, strict=True)):
                object.__setattr__(config, name, value)
            return config

        jax.tree_util.register_pytree_with_keys(cls, flatten, unflatten)
        cls.static_fields = static
        return cls

    return register


def replaced(config: T, **changes: Any) -> T:
    """``config`` with fields replaced; a nested configuration's field takes a dict of its own changes.

    ``replaced(PipelineConfig(), capacity=16, corners={"threshold": 0.4})``.
    """
    resolved = {
        name: replaced(getattr(config, name), **value) if isinstance(value, dict) else value
        for name, value in changes.items()
    }
    return dataclasses.replace(config, **resolved)


def check_positive(config: Any, *names: str) -> None:
    """Raise ValueError unless each field ``names`` of ``config`` is > 0."""
    for name in names:
        if not getattr(config, name) > 0:
            raise ValueError(f"{type(config).__name__}.{name} must be > 0, got {getattr(config, name)}")


def check_non_negative(config: Any, *names: str) -> None:
    """Raise ValueError unless each field ``names`` of ``config`` is >= 0."""
    for name in names:
        if not getattr(config, name) >= 0:
            raise ValueError(f"{type(config).__name__}.{name} must be >= 0, got {getattr(config, name)}")


def check_fraction(config: Any, name: str, upper: float = 1.0, closed: bool = True) -> None:
    """Raise ValueError unless field ``name`` of ``config`` is in [0, upper] (``closed``) or [0, upper)."""
    value = getattr(config, name)
    if not (0 <= value <= upper if closed else 0 <= value < upper):
        interval = f"[0, {upper}]" if closed else f"[0, {upper})"
        raise ValueError(f"{type(config).__name__}.{name} must be in {interval}, got {value}")


def scaled(value: Float[ArrayLike, ""], size: int, reference: int) -> Float[ArrayLike, ""]:
    """``value``, given for a ``reference``-pixel side, for a side of ``size`` pixels."""
    return value * size / reference
