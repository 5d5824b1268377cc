"""The top-level `ppd` group: click's own errors (usage, missing files) in ppd's one-line style,
readable help (no `<bool>`, `PATHS...`, words for types), light value conversion."""

from __future__ import annotations

import contextlib
import signal
import sys
from collections.abc import Sequence
from typing import Any

import typer
from typer.core import TyperArgument, TyperGroup

from daemon.cli import coerce
from daemon.cli.errors import error, known_error
from poisoner.errors import ExitStatus

try:  # typer >= 0.22 vendors click: its exceptions are the ones raised
    from typer._click.exceptions import ClickException, NoArgsIsHelpError, UsageError
except ImportError:  # pragma: no cover - older typer on the real click
    from click.exceptions import ClickException, NoArgsIsHelpError, UsageError  # type: ignore[assignment]

_TYPE_WORDS = {"int": "N", "int range": "N", "float": "NUM", "float range": "NUM", "path": "PATH",
               "list[Path]": "PATH", "list[str]": "TEXT"}  # fmt: skip


def _readable_type(param: Any, original: Any) -> Any:
    """`--workers N` and `--dataset DATASET`, not `<int range>` and `<str>`."""

    def display(ctx: Any) -> str | None:
        label = original(ctx)
        if label is None or not label.startswith("<"):
            return label
        word = label.strip("<>")
        return _TYPE_WORDS.get(word) or (param.name or "value").upper()

    return display


def _tidy_param(param: Any) -> None:
    if param.param_type_name == "option":
        if getattr(param, "is_flag", False) or param.count:
            param.metavar = ""
        elif param.metavar is None:
            param.display_type_rich = _readable_type(param, param.display_type_rich)
    elif isinstance(param, TyperArgument):
        name = (param.name or "arg").upper()
        usage = name if param.required else f"[{name}]"
        usage += "..." if param.nargs != 1 else ""
        # typer's own display hooks, replaced on this parameter object (setattr: they are methods)
        setattr(param, "display_type_rich", lambda ctx: None)  # noqa: B010
        setattr(param, "_usage_display_name", lambda usage=usage: usage)  # noqa: B010
        setattr(param, "_rich_display_name", lambda name=name: name)  # noqa: B010


def tidy_help(command: Any) -> None:
    """Readable help in every command, set on the parameter objects once per process."""
    for param in command.params:
        if not getattr(param, "_ppd_tidy", False):
            param._ppd_tidy = True
            _tidy_param(param)
    for sub in getattr(command, "commands", {}).values():
        tidy_help(sub)


class PpdGroup(TyperGroup):
    """typer's group with click's errors (usage, missing files) in ppd's one-line style."""

    def invoke(self, ctx: Any) -> Any:
        # typer turns a KeyboardInterrupt inside a command into a silent Exit(130): a Ctrl-C'd
        # `ppd verify` ended with nothing said. The line is said here, where the command ended.
        try:
            return super().invoke(ctx)
        except KeyboardInterrupt:
            sys.stderr.write("ppd: interrupted\n")
            raise typer.Exit(ExitStatus.INTERRUPTED) from None

    def main(
        self,
        args: Sequence[str] | None = None,
        prog_name: str | None = None,
        complete_var: str | None = None,
        standalone_mode: bool = True,
        windows_expand_args: bool = True,
        **extra: Any,
    ) -> Any:
        if signal.getsignal(signal.SIGINT) is not signal.SIG_IGN:  # loaded: Ctrl-C is Python's again
            with contextlib.suppress(ValueError):  # not the main thread: its handler is not ours
                signal.signal(signal.SIGINT, signal.default_int_handler)
        tidy_help(self)
        coerce.install()
        args = _verbosity_first(self, list(sys.argv[1:] if args is None else args))
        try:
            rv = super().main(
                args=args, prog_name=prog_name or "ppd", complete_var=complete_var,
                standalone_mode=False, windows_expand_args=windows_expand_args, **extra,
            )  # fmt: skip
            code = rv if isinstance(rv, int) else ExitStatus.OK
        except Exception as exc:
            code = _exit_code(exc)
        except KeyboardInterrupt:  # one line, never a traceback (ppd poison says more itself)
            sys.stderr.write("ppd: interrupted\n")
            code = ExitStatus.INTERRUPTED
        if not standalone_mode:
            return code
        sys.exit(code)


_VERBOSE = frozenset({"-v", "-vv", "-vvv", "--verbose"})


def _verbosity_first(group: Any, args: list[str]) -> list[str]:
    """args with a -v given after the command moved before it, where the group's -v lives: `ppd
    restore X -v` said "No such option: -v" (a black-box review). A command with a -v of its own
    (`ppd store rebuild -v`) keeps it; nothing after `--` moves."""
    command, at = group, None
    for i, word in enumerate(args):
        if word == "--":
            break
        sub = getattr(command, "commands", {}).get(word) if not word.startswith("-") else None
        if sub is None:
            if at is not None and not word.startswith("-"):
                break  # the first argument of the command: its subcommands end here
            continue
        command, at = sub, i
    if at is None or any("-v" in getattr(p, "opts", ()) for p in command.params):
        return args
    end = args.index("--") if "--" in args else len(args)
    moved = [w for w in args[at + 1 : end] if w in _VERBOSE]
    kept = [w for w in args[at + 1 : end] if w not in _VERBOSE]
    return moved + args[: at + 1] + kept + args[end:]


def _exit_code(exc: Exception) -> int:
    """The exit code of an exception that reached the top, its one line printed; a bug re-raised."""
    if isinstance(exc, NoArgsIsHelpError):  # `ppd` alone: the help, on stdout, is the answer
        sys.stdout.write(exc.format_message() + "\n")
        return ExitStatus.OK
    if isinstance(exc, UsageError):
        hint = f" (see `{exc.ctx.command_path} --help`)" if exc.ctx is not None else ""
        error(f"{exc.format_message()}{hint}")
        return exc.exit_code
    if isinstance(exc, ClickException):
        error(exc.format_message())
        return exc.exit_code
    if isinstance(exc, typer.Abort):  # click's word for a KeyboardInterrupt it caught
        sys.stderr.write("ppd: interrupted\n")
        return ExitStatus.INTERRUPTED
    code = known_error(exc)
    if code is None:
        raise exc
    return code
