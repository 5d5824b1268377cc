"""Plain option values (ints, floats, text, flags, paths) converted without loading pydantic.

typer (0.29) converts every option value through a pydantic TypeAdapter, and importing pydantic
costs about 55 ms, a third of the start-up budget of `ppd status` and `ppd poison --help`
(issue 19), and about 100 ms of CPU of every `ppd poison DATASET` run (issue 30: 3% of 24 PNGs'
whole process). For the plain forms (`3`, `-1`, `0.5`, text, a list of text, True/False, a path
or a list of paths without typer's path checks) the answer is the one pydantic gives, so it is
computed here; anything else (choices, `1e3`, an out-of-range or malformed value, a path option
asking typer to check or resolve it) goes to typer's own converter, which gives its own result or
error message. With a typer that has no such converter this module does nothing.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any, cast, get_args, get_origin

_INT = re.compile(r"-?[0-9]+")
_FLOAT = re.compile(r"-?([0-9]+(\.[0-9]*)?|\.[0-9]+)")
_NOT_PLAIN = object()


def plain_value(annotation: Any, value: Any, low: float | None = None, high: float | None = None) -> Any:
    """The converted value, or _NOT_PLAIN when typer's converter must decide."""
    if get_origin(annotation) is list:
        (item_type,) = get_args(annotation) or (None,)
        if item_type is not str or not isinstance(value, list | tuple):
            return _NOT_PLAIN
        return [v for v in value] if all(type(v) is str for v in value) else _NOT_PLAIN
    if annotation is str:
        return value if type(value) is str else _NOT_PLAIN
    if annotation is bool:
        return value if type(value) is bool else _NOT_PLAIN
    if annotation is int:
        if type(value) is str and _INT.fullmatch(value):
            value = int(value)
        number = value if type(value) is int else _NOT_PLAIN
    elif annotation is float:
        if type(value) is str and _FLOAT.fullmatch(value):
            value = float(value)
        number = float(value) if type(value) in (int, float) else _NOT_PLAIN
    else:
        return _NOT_PLAIN
    if not isinstance(number, int | float):
        return _NOT_PLAIN
    if (low is not None and number < low) or (high is not None and number > high):
        return _NOT_PLAIN
    return number


def plain_path(annotation: Any, value: Any, info: Any) -> Any:
    """A Path or list[Path] value as typer 0.29 gives it, or _NOT_PLAIN.

    typer makes Path(text) of each item (pydantic), then checks what the parameter's flags ask
    (coerce_cli_path: exists, file_okay, dir_okay, readable, writable, resolve_path, allow_dash,
    path_type), for a list's items too. Only the defaults are taken here, whose one check is that an
    existing path is readable; an unreadable one goes to typer for its message."""
    defaults = (info.exists, info.file_okay, info.dir_okay, info.writable, info.readable,
                info.resolve_path, info.allow_dash, info.path_type)  # fmt: skip
    if defaults != (False, True, True, False, True, False, False, None):
        return _NOT_PLAIN
    if get_origin(annotation) is list:
        if get_args(annotation) != (Path,) or not isinstance(value, list | tuple):
            return _NOT_PLAIN
        paths = [_readable_path(v) for v in value]
        return _NOT_PLAIN if any(p is _NOT_PLAIN for p in paths) else paths
    return _readable_path(value) if annotation is Path else _NOT_PLAIN


EMPTY_PATH = "an empty path (an unset variable in a script?); give a file or folder ('.' for this one)"


def empty_path(annotation: Any, value: Any) -> bool:
    """Whether a path parameter got the empty text, which Path() reads as '.': `ppd poison "$DIR"`
    with DIR unset would patch every photo under the working folder."""
    if annotation is Path or (get_origin(annotation) is list and get_args(annotation) == (Path,)):
        values = value if isinstance(value, list | tuple) else [value]
        return any(type(v) is str and v == "" for v in values)
    return False


def _readable_path(value: Any) -> Any:
    # pydantic makes Path(value) of any text; the empty and the NUL-bearing go to typer to judge.
    # typer stats the Path (a trailing "/" dropped), so the check does too.
    if type(value) is not str or value == "" or "\0" in value:
        return _NOT_PLAIN
    path = Path(value)
    if os.path.exists(path) and not os.access(path, os.R_OK):
        return _NOT_PLAIN
    return path


def install() -> None:
    """From now on, every typer parameter of this process converts plain values here first."""
    try:
        from typer._click.exceptions import BadParameter
        from typer._coercion import RuntimeParam, build_runtime_param
        from typer.core import _TyperParameter
    except ImportError:  # another typer: nothing to do
        return
    if getattr(_TyperParameter, "_ppd_plain", False):
        return

    class PlainRuntimeParam(RuntimeParam):  # a frozen dataclass through its base
        def _coerce_value(self, value: Any, param: Any, ctx: Any) -> Any:
            if empty_path(self.annotation, value):
                raise BadParameter(EMPTY_PATH, ctx=ctx, param=param)
            info = self.parameter_info
            if info.parser is None and not info.clamp:
                converted = plain_value(self.annotation, value, info.min, info.max)
                if converted is _NOT_PLAIN:
                    converted = plain_path(self.annotation, value, info)
                if converted is not _NOT_PLAIN:
                    return converted
            real = build_runtime_param(param.type_descriptor)
            param._runtime_param = real  # the next value goes straight to typer's converter
            return real._coerce_value(value, param=param, ctx=ctx)

    typers_own = _TyperParameter.get_runtime_param

    def get_runtime_param(self: Any) -> Any:
        # An absent value (None) never reaches _coerce_value, yet typer builds its converter
        # first: a light one here means `--help` alone loads no pydantic.
        descriptor = self.type_descriptor
        if self._runtime_param is None and descriptor.file_annotation is None:
            self._runtime_param = PlainRuntimeParam(
                parameter_info=descriptor.parameter_info, annotation=descriptor.annotation
            )
        return typers_own(self)

    patched = cast(Any, _TyperParameter)  # typer's private class, patched on purpose (test_packaging)
    patched.get_runtime_param = get_runtime_param
    patched._ppd_plain = True
