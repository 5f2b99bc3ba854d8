"""Pydantic models derived from the core's dataclasses, so that a field is declared once: in
the core (its name, type and order), while a storage record or a wire model adds only what is
its own (what a record from before the field reads as, a description for the OpenAPI schema,
numbers that may be null because JSON has no Infinity).

>>> from dataclasses import dataclass
>>> @dataclass
... class Point:
...     x: float
...     label: str = ""
>>> Wire = model_of(Point, "Wire", nullable_numbers=True, docs={"x": "Abscissa, px"})
>>> Wire(x=None).model_dump()
{'x': None, 'label': ''}
"""

from __future__ import annotations

import dataclasses
import types
import typing
from collections.abc import Iterable, Mapping
from typing import Any

from pydantic import BaseModel, Field, create_model

#: A field's default when a caller gives none (required).
REQUIRED: Any = ...


def nullable(annotation: Any) -> Any:
    """``annotation`` with every ``float`` in it (also inside ``dict``, ``list`` and unions)
    allowing None: the JSON form of a number that may not be finite."""
    if annotation is float:
        return float | None
    origin = typing.get_origin(annotation)
    if origin is None:
        return annotation
    args = tuple(nullable(arg) for arg in typing.get_args(annotation))
    if origin in (typing.Union, types.UnionType):
        return typing.Union[args]  # noqa: UP007 (built from a tuple)
    return origin[args]


class _Factory(typing.NamedTuple):
    """A default made per instance (a dataclass's or a model's ``default_factory``)."""

    make: Any


def _core_fields(source: type) -> list[tuple[str, Any, Any, str | None]]:
    """(name, annotation, default, description) of a dataclass's or a model's fields, in order
    (the default :data:`REQUIRED`, or a :class:`_Factory`)."""
    if isinstance(source, type) and issubclass(source, BaseModel):
        found = []
        for name, info in source.model_fields.items():
            if info.default_factory is not None:
                default: Any = _Factory(info.default_factory)
            else:
                default = REQUIRED if info.is_required() else info.default
            found.append((name, info.annotation, default, info.description))
        return found
    if not dataclasses.is_dataclass(source):
        raise TypeError(f"{source!r} is neither a dataclass nor a pydantic model")
    hints = typing.get_type_hints(source)
    found = []
    for field in dataclasses.fields(source):
        if field.default is not dataclasses.MISSING:
            default = field.default
        elif field.default_factory is not dataclasses.MISSING:
            default = _Factory(field.default_factory)
        else:
            default = REQUIRED
        found.append((field.name, hints[field.name], default, field.metadata.get("doc")))
    return found


def model_of(
    source: type,
    name: str,
    *,
    base: type[BaseModel] | None = None,
    exclude: Iterable[str] = (),
    defaults: Mapping[str, Any] | None = None,
    docs: Mapping[str, str] | None = None,
    nullable_numbers: bool = False,
    module: str | None = None,
    doc: str | None = None,
) -> type[BaseModel]:
    """A pydantic model with ``source``'s fields (a dataclass or a model), in its order.

    Parameters
    ----------
    source : type
        The core's declaration.
    name : str
        The model's name (OpenAPI's too).
    base : type of BaseModel, optional
        Its base (configuration, validators, methods).
    exclude : iterable of str
        Fields not carried.
    defaults : mapping, optional
        Defaults over the source's (a stored record from before a field was added).
    docs : mapping, optional
        Descriptions over the source's; a name that is not a field is a ``KeyError``.
    nullable_numbers : bool
        Every ``float`` may be null (:func:`nullable`).
    module, doc : str, optional
        The model's ``__module__`` and docstring.
    """
    defaults, docs, skipped = dict(defaults or {}), dict(docs or {}), set(exclude)
    fields: dict[str, Any] = {}
    for field_name, annotation, default, description in _core_fields(source):
        if field_name in skipped:
            continue
        if nullable_numbers:
            annotation = nullable(annotation)
        value = defaults.pop(field_name, default)
        description = docs.pop(field_name, description)
        if isinstance(value, _Factory):
            info = Field(default_factory=value.make, description=description)
        else:
            info = Field(value, description=description)
        fields[field_name] = (annotation, info)
    if defaults or docs:
        raise KeyError(f"{name}: not fields of {source.__name__}: {sorted({*defaults, *docs})}")
    options: dict[str, Any] = {"__module__": module or source.__module__}
    if base is not None:
        options["__base__"] = base
    model = create_model(name, **options, **fields)
    if doc is not None:
        model.__doc__ = doc
    return model
