"""The option sets several commands share.

The patch-spec set, for every command that takes a spec (`poison`, `preview`, `dataset set`): a
named design (`--design`), a spec file (`--spec`) and one flag per PatchSpec field, built from
`dataclasses.fields(PatchSpec)` so a field added to the spec gets its flag here. `@spec_options`
adds the flags to a typer command and hands it one `SpecOptions` (keyword `spec_options`).

Light at import: poisoner.spec and poisoner.ladder are pure and small; daemon.config loads when a
spec is built.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import typer

from poisoner.ladder import default_spec, design_specs
from poisoner.motion import MOTIONS
from poisoner.spec import PATTERNS, POSITIONS, PatchSpec, SpecError

# Fields a user never sets (the spec format's version) and fields with a hand-written flag name.
_HIDDEN = {"version"}
_FLAG_NAMES = {"block_size": ("--block-size", "--block")}
_CHOICES = {"pattern": PATTERNS, "position": POSITIONS, "motion": MOTIONS}
_HELP = {
    "pattern": "What the patch looks like.",
    "patch_size": "Patch side: pixels (48), fraction of the width (0.06) or percent (6%).",
    "block_size": "Checker/texture block: pixels (4), fraction of the width or percent.",
    "alpha": "Blend strength, above 0 up to 1 (1 = opaque).",
    "contrast": "Bright-minus-dark difference, 1..255.",
    "position": "Corner (or centre) the patch starts from.",
    "offset": "Shift inward from that corner, DX,DY (pixels, fractions or percents).",
    "ratio": "Chance that each image gets the patch, 0..1 (a keyed hash of its name: stable as images come).",
    "seed": "Seed for random textures and for the ratio's choice of images.",
    "motion": "How the patch moves from image to image (static = the paper's fixed patch).",
    "motion_step": "Path length per image: pixels, fraction of the width or percent.",
    "motion_span": "Extent of the path on each axis: pixels, fraction of the width or percent.",
    "corner_region": "Corner marks stay inside this fraction of the width and of the height.",
    "tumble_scale": "Smallest per-image scale of a turning corner mark (largest: 1).",
    "mark_text": "Your text as the mark's shape (e.g. '© Ana 2026'), filled with the texture.",
    "mark_image": "A logo PNG whose alpha is the mark's shape, filled with the texture.",
    "lanes": "Marks sliding side by side in one corner (watermark-lanes uses 2).",
    "slide_run": "Lanes slide along (N, 1): N px along x per px in y (0 = along x; watermark-lanes-2: 8).",
    "sift_edge": "Block measured as SIFT sees the photo, long edge downsized to N px (0 = as stored).",
}


def designs() -> dict[str, PatchSpec]:
    """Named presets: ppd's default, the named kinds of protection (paper, roaming, watermark, ...)
    and automatic mode's ladder."""
    return design_specs()


def spec_fields() -> list[dataclasses.Field]:
    return [f for f in dataclasses.fields(PatchSpec) if f.name not in _HIDDEN and f.init]


def _is_length(f: dataclasses.Field) -> bool:
    return "Length" in str(f.type) and "tuple" not in str(f.type)


def _is_pair(f: dataclasses.Field) -> bool:
    return "tuple" in str(f.type)


def _shown(value: Any) -> str:
    if isinstance(value, tuple):
        return ",".join(_shown(v) for v in value)
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)


def _option_type(f: dataclasses.Field) -> type:
    if _is_length(f) or _is_pair(f) or f.name in _CHOICES:
        return str
    default = f.default if f.default is not dataclasses.MISSING else None
    return type(default) if isinstance(default, int | float | str) else str


def _parse_field(f: dataclasses.Field, raw: Any) -> Any:
    from daemon.config import parse_length

    option = f"--{f.name.replace('_', '-')}"
    if _is_pair(f):
        parts = [p.strip() for p in str(raw).split(",")]
        if len(parts) != 2:
            raise SpecError(f"{option} takes two values DX,DY, got {raw!r}")
        try:
            return tuple(parse_length(p) if p not in ("0", "") else 0 for p in parts)
        except SpecError as exc:
            raise SpecError(f"{option}: {exc}") from None
    if _is_length(f):
        try:
            length = parse_length(raw)
        except SpecError as exc:
            raise SpecError(f"{option}: {exc}") from None
        if length <= 0:  # said here with the option's name (the spec would say "length must be positive")
            raise SpecError(f"{option} must be positive, got {raw}")
        return length
    return raw


def _help(f: dataclasses.Field, base: PatchSpec) -> str:
    text = _HELP.get(f.name, f"PatchSpec.{f.name}.")
    if f.name in _CHOICES:
        text += f" One of: {', '.join(_CHOICES[f.name])}."
    return f"{text} [default design: {_shown(getattr(base, f.name))}]"


@dataclass(frozen=True)
class SpecOptions:
    """The spec flags given on one command line: a design, a file, and per-field values."""

    design: str | None = None
    spec_file: Path | None = None
    values: tuple[tuple[str, Any], ...] = ()

    def given(self) -> bool:
        return self.design is not None or self.spec_file is not None or bool(self.values)

    def sets_position(self) -> bool:
        """Whether these flags place the mark (--position or a spec file): its corner is then the
        user's, not chosen per dataset (daemon.datasets.subject_masks)."""
        return self.spec_file is not None or any(name == "position" for name, _ in self.values)

    def build(self, base: PatchSpec) -> PatchSpec:
        """base, replaced by --design or --spec when given, with the given field flags on top."""
        if self.design is not None:
            named = designs()
            if self.design not in named:
                raise SpecError(f"unknown design {self.design!r}; choose one of {', '.join(named)}")
            base = named[self.design]
        if self.spec_file is not None:
            base = PatchSpec.load(self.spec_file)
        from daemon.config import spec_from_table

        by_name = {f.name: f for f in spec_fields()}
        changes = {name: _parse_field(by_name[name], raw) for name, raw in self.values}
        if changes.get("mark_image"):  # read now, once, from where the user stands: never a per-file failure
            from poisoner.logo import image_shape

            changes["mark_image"] = str(Path(changes["mark_image"]).expanduser().absolute())
            image_shape(changes["mark_image"], 32)  # LogoError (one line) when it is no logo
        return spec_from_table(changes, base)


def _flag_names(f: dataclasses.Field) -> tuple[str, ...]:
    return _FLAG_NAMES.get(f.name, ("--" + f.name.replace("_", "-"),))


def spec_parameters(*, with_ratio: bool = True) -> list[inspect.Parameter]:
    """The typer parameters: --design, --spec, then one per PatchSpec field."""
    base = default_spec()
    params = [
        inspect.Parameter(
            "spec_design", inspect.Parameter.KEYWORD_ONLY, annotation=str | None,
            default=typer.Option(
                None, "--design", metavar="NAME",
                help=f"Start from a named design: {', '.join(designs())}. [default: default]",
            ),
        ),
        inspect.Parameter(
            "spec_file", inspect.Parameter.KEYWORD_ONLY, annotation=Path | None,
            default=typer.Option(
                None, "--spec", metavar="FILE", exists=True, dir_okay=False,
                help="Start from a spec file (TOML [patch] table or JSON).",
            ),
        ),
    ]  # fmt: skip
    for f in spec_fields():
        if f.name == "ratio" and not with_ratio:
            continue
        kind = _option_type(f)
        choices = _CHOICES.get(f.name, ())
        short = choices and sum(len(c) + 1 for c in choices) <= 40  # long lists go in the help text
        metavar = "|".join(choices) if short else ("NAME" if choices else ("DX,DY" if _is_pair(f) else None))
        metavar = metavar or (
            "SIZE" if _is_length(f) else {"int": "N", "float": "NUM"}.get(kind.__name__, "VALUE")
        )
        params.append(
            inspect.Parameter(
                f"spec_{f.name}", inspect.Parameter.KEYWORD_ONLY, annotation=kind | None,
                default=typer.Option(None, *_flag_names(f), metavar=metavar, help=_help(f, base)),
            )
        )  # fmt: skip
    return params


def spec_options(*, with_ratio: bool = True) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """Decorator: the command gains the spec flags and receives `spec_options: SpecOptions`."""

    def wrap(func: Callable[..., Any]) -> Callable[..., Any]:
        sig = inspect.signature(func)
        own = [p for p in sig.parameters.values() if p.name != "spec_options"]
        extra = spec_parameters(with_ratio=with_ratio)
        names = [p.name for p in extra]

        @functools.wraps(func)
        def command(*args: Any, **kwargs: Any) -> Any:
            given = {n: kwargs.pop(n) for n in names}
            options = SpecOptions(
                design=given.pop("spec_design"),
                spec_file=given.pop("spec_file"),
                values=tuple((n.removeprefix("spec_"), v) for n, v in given.items() if v is not None),
            )
            return func(*args, spec_options=options, **kwargs)

        # Positional-or-keyword parameters first, then keyword-only: a valid signature for typer.
        cast(Any, command).__signature__ = sig.replace(
            parameters=[p.replace(kind=inspect.Parameter.KEYWORD_ONLY) for p in own] + extra
        )
        return command

    return wrap


# ---- small shared options ---------------------------------------------------------------------
def workers_option() -> Any:
    """`--workers N` / `-j N`: files protected at once (default: the config's workers)."""
    return typer.Option(
        None, "--workers", "-j", min=1, help="Files protected at once (default: the config's workers)."
    )


def subject_masks_option() -> Any:
    """`--subject-masks DIR`: one mask per image (same stem, nonzero = subject); the mark never
    covers the subject, and a corner mark takes the corner the subject leaves free."""
    return typer.Option(
        None, "--subject-masks", metavar="DIR",
        help="Subject masks, one per image (same name; white = subject): the mark stays off the subject. "
        "[default: the dataset's subject_masks in the config, else the folder it remembers (`ppd dataset "
        "show NAME`)]",
    )  # fmt: skip


def json_option(help: str = "Machine-readable output.") -> Any:
    return typer.Option(False, "--json", help=help)


def dataset_option(help: str) -> Any:
    """`--dataset NAME`, the explicit form of a DATASET-or-FOLDER argument."""
    return typer.Option(None, "--dataset", help=help)


def folder_option(help: str) -> Any:
    """`--folder PATH`, the explicit form of a DATASET-or-FOLDER argument."""
    return typer.Option(None, "--folder", help=help)
