"""Typer's conversion of option values, without pydantic for the plain values georef's commands take.

Typer (0.2x) converts every parameter's value through a pydantic ``TypeAdapter`` that it builds on first use, even
for an option left at its default, and building the first one imports pydantic: 0.15 s of CPU, a tenth of a ``georef
process`` on a 15-minute flight before this module (measured with cProfile and ``python -X importtime``). For the
annotations georef's commands declare (``str``, ``int``, ``float``, ``bool``, ``pathlib.Path``, a string ``Enum`` of
choices, and lists of these) the conversion of a plain command-line string is plain Python: the string itself,
``int``/``float`` of an ASCII numeral, ``Path(text)`` followed by typer's own path checks
(:func:`typer._param_types.coerce_cli_path`), typer's own choice matching
(:func:`typer._param_types.coerce_cli_choice`). :class:`PlainCoercionCommand` and :class:`PlainCoercionGroup` (the
command and group classes of georef's typer app) give each such parameter that conversion; a value that is not plain
(``"1_000"``, ``" 2 "``, ``"1.0"`` for an int, a choice that matches nothing, anything that is not a string) goes to
typer's own pydantic conversion, so the results and the error messages stay typer's. ``tests/cli/test_coercion.py``
checks the two agree, value by value, for every parameter of every command, and that ``georef process`` no longer
imports pydantic.

It uses typer's internals (``typer.core._TyperParameter``, ``typer._coercion``, ``typer._param_types``): if a typer
release changes them, :data:`AVAILABLE` is False, the classes behave as typer's own (the test then fails, saying
so).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Any, get_args, get_origin

from typer.core import TyperCommand, TyperGroup

try:
    from typer._coercion import RuntimeParam, build_runtime_param
    from typer._param_types import coerce_cli_choice, coerce_cli_path
    from typer.core import _TyperParameter

    AVAILABLE = True
except ImportError:  # pragma: no cover - a typer without these internals: its own conversion throughout
    AVAILABLE = False

#: ASCII numerals that ``int`` and ``float`` read exactly as pydantic's lax mode does
_INT = re.compile(r"[+-]?[0-9]+\Z")
_FLOAT = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?\Z")


class _NotPlainError(Exception):
    """The value is not one this module converts: typer's own conversion takes it."""


Converter = Callable[[Any, Any, Any], Any]


def _leaf_converter(annotation: Any, info: Any) -> Converter | None:
    """Conversion of one string for ``annotation`` with the parameter's settings ``info``, or None."""
    if info.parser is not None:
        return None
    if annotation in (bool, str):
        def exact(value: Any, param: Any, ctx: Any) -> Any:
            if type(value) is not annotation:
                raise _NotPlainError
            return value
        return exact
    if annotation in (int, float):
        if info.min is not None or info.max is not None or info.clamp:
            return None
        pattern = _INT if annotation is int else _FLOAT

        def to_number(value: Any, param: Any, ctx: Any) -> Any:
            if type(value) is not str or not pattern.match(value):
                raise _NotPlainError
            return annotation(value)  # correctly rounded, as pydantic reads it
        return to_number
    if isinstance(annotation, type) and issubclass(annotation, Enum):
        choices = tuple(annotation)

        def to_choice(value: Any, param: Any, ctx: Any) -> Any:
            if type(value) is not str:
                raise _NotPlainError
            try:
                return coerce_cli_choice(value, choices=choices, case_sensitive=info.case_sensitive, ctx=ctx)
            except ValueError:
                raise _NotPlainError from None  # typer's message for a wrong choice
        return to_choice
    if isinstance(annotation, type) and issubclass(annotation, Path) and info.path_type in (None, annotation):
        def to_path(value: Any, param: Any, ctx: Any) -> Any:
            if type(value) is not str:
                raise _NotPlainError
            return coerce_cli_path(annotation(value), info, path_type=annotation, param=param, ctx=ctx)
        return to_path
    return None


def _converter(annotation: Any, info: Any) -> Converter | None:
    """The conversion of a parameter's value (a string, or a list of them for ``list[...]``), or None."""
    if get_origin(annotation) is list:
        args = get_args(annotation)
        leaf = _leaf_converter(args[0], info) if len(args) == 1 else None
        if leaf is None:
            return None

        def to_list(value: Any, param: Any, ctx: Any) -> Any:
            items = value if isinstance(value, (list, tuple)) else [value]
            return [leaf(item, param, ctx) for item in items]
        return to_list
    return _leaf_converter(annotation, info)


if AVAILABLE:
    @dataclass(frozen=True)
    class PlainRuntimeParam(RuntimeParam):
        """A parameter's conversion: :attr:`convert` for plain values, typer's own for the rest."""

        convert: Converter

        def _coerce_value(self, value: Any, param: Any, ctx: Any) -> Any:
            try:
                return self.convert(value, param, ctx)
            except _NotPlainError:
                return build_runtime_param(param.type_descriptor)._coerce_value(value, param, ctx)


def install(params: Any) -> None:
    """Give every parameter in ``params`` whose annotation this module knows the plain conversion."""
    if not AVAILABLE:
        return
    for param in params:
        if not isinstance(param, _TyperParameter) or param._runtime_param is not None:
            continue
        descriptor = param.type_descriptor
        if descriptor.file_annotation is not None:
            continue
        convert = _converter(descriptor.annotation, descriptor.parameter_info)
        if convert is not None:
            param._runtime_param = PlainRuntimeParam(parameter_info=descriptor.parameter_info,
                                                     annotation=descriptor.annotation, convert=convert)


class PlainCoercionCommand(TyperCommand):
    """Typer's command, converting plain values without pydantic (:func:`install`; ``@app.command(cls=...)``)."""

    def parse_args(self, ctx: Any, args: list[str]) -> list[str]:
        install(self.get_params(ctx))  # its options, arguments and --help
        return super().parse_args(ctx, args)


class PlainCoercionGroup(TyperGroup):
    """Typer's command group, converting its own options' plain values without pydantic (``typer.Typer(cls=...)``)."""

    def parse_args(self, ctx: Any, args: list[str]) -> list[str]:
        install(self.get_params(ctx))  # --version, --help
        return super().parse_args(ctx, args)
