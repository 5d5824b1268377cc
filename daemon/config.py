"""ppd's configuration: one typed schema (msgspec structs) loaded from `config_dir/config.toml`.

Every key is optional; what is missing comes from the embedded defaults below. Layout:

    workers = 2                 # concurrent protect jobs in the daemon
    debounce_seconds = 2.0      # quiet time before a changed file is processed
    publish_dir = ""            # optional: protected files are moved here ("" = stay in the outbox)

    [patch]                     # fields replaced on the default spec; sizes: 48, 0.06 or "6%"
    design = "default"          # the spec the fields below replace fields of (`ppd poison --design`):
                                # "default" = poisoner.ladder.default_spec(), "watermark-lanes-2":
                                # two identical texture marks sliding in one corner, off the subject
                                # (docs/DESIGNS.md), its corner chosen per dataset unless `position`
                                # is set; "roaming" = the moving square anywhere in the frame;
                                # "paper" = the paper's static corner checkerboard
    patch_size = 0.06

    [verification]
    enabled = true
    every_new_files = 20        # verify a dataset after this many newly protected files
    period_hours = 24.0         # ... and at least this often while it keeps changing
    profiles = ["default", "hardened", "published", "global", "masked"]
                                # the headline verdict counts all five, masked (the attacker
                                # masks the corner regions) included (verifier.verdict.HEADLINE_PROFILES)
    splat = false               # also train clean/poisoned Gaussian splats (~6 more minutes per 40 views)
    splat_budget_s = 150.0      # splat training seconds per side
    seeds = 1                   # COLMAP runs per attacker on the patched set (`ppd verify --seeds`)
    keep_runs = 5               # run folders (SfM models) kept per dataset; older ones are deleted

    [vault]
    max_bytes = 0               # 0 = unlimited; when full, protection is refused (never silent deletion)

    [privacy]
    keep_location = false       # true: patched files keep GPS/place metadata (default: removed)

    [daemon]
    quarantine_dir = ""         # files `ppd watch` cannot patch go here ("": <outbox>/../ppd-quarantine)
    max_debounce_seconds = 30.0 # the quiet time grows (doubles) while a file keeps changing, up to this
    incomplete_wait_seconds = 120.0  # an incomplete file is waited for until unchanged this long

    [limits]
    max_megapixels = 80.0       # larger images are refused before decoding (WebP: a fifth, HEIF: a third)
    max_memory_mb = 1024.0      # what patching may take at once, all workers together, in MB (estimated
                                # from the header: decoded bytes x the format's measured working copies);
                                # a file that alone needs more is refused, others wait their turn

    [visibility]                # automatic mode's budget: what a viewer sees (FLIP, verifier.visibility),
    max_noticeable_area = 0.01  # worst sample image; fraction of the picture with FLIP > 0.5
    max_p999_vs_jpeg = 0.0      # FLIP p99.9 / a JPEG q85 re-encode's (0 = not gated)
    corner_only = false         # true: every changed pixel inside one corner region (watermark-like)
    corner_region = 0.2         # that region: 20% of the width x 20% of the height
    display_width = 1920        # the viewing condition: the photo shown this many px wide (or its own width)

    [preflight]                 # automatic mode's check on a sample of the dataset (docs/AUTO.md)
    sample_size = 12
    time_budget_s = 900.0
    profiles = ["default", "hardened"]
    camera_params = ""          # known intrinsics "fx,fy,cx,cy,k1,k2,p1,p2" ("" = COLMAP estimates)

    [datasets.NAME]             # per-dataset overrides, applied when the dataset gets its spec
    publish_dir = "/srv/www/NAME"
    subject_masks = "/data/NAME/masks"  # one mask per image (same stem; nonzero = subject): the mark
                                # never covers a masked pixel, a corner mark takes the corner the
                                # subject leaves free; never inside the outbox (it would be published)
    spec = "auto"               # automatic mode: the verifier picks the patch (docs/AUTO.md)
    [datasets.NAME.patch]
    position = "bottom-right"

Defaults live in the structs below (and, for [visibility] / [preflight], in the verifier's own
structs, verifier.auto_options). A bad value is one line naming the file and the key. An empty
string for a folder or an optional setting means "not set" (TOML has no null).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import re
import tomllib
from pathlib import Path
from typing import Any, ClassVar

import msgspec

from daemon.paths import AppPaths
from poisoner.errors import ExitStatus, PpdError
from poisoner.ladder import default_spec, design_specs, strongest_spec
from poisoner.spec import PatchSpec, SpecError
from verifier.auto_options import PreflightOptions, Profile, VisibilityBudget

AUTO_SPEC = "auto"  # `spec = "auto"` in [datasets.NAME]
MAX_SEEDS = 10  # [verification] seeds and `ppd verify --seeds`: each seed is one more mapping per profile


def seeds_problem(seeds: int) -> str | None:
    """Why a count of COLMAP seeds is refused ([verification] seeds, `ppd verify --seeds`); None: taken."""
    return None if 0 < seeds <= MAX_SEEDS else f"must be a whole number from 1 to {MAX_SEEDS}, got {seeds!r}"

# folders: "" = not set (TOML has no null)
_EMPTY_MEANS_UNSET = ("publish_dir", "quarantine_dir", "subject_masks")
_OLD_BUDGET_KEYS = ("min_ssim", "max_lpips")


class ConfigError(PpdError, ValueError):
    """config.toml cannot be read or holds an invalid value (message = one line)."""

    exit_status = ExitStatus.USAGE


def parse_length(value: Any) -> int | float:
    """A patch/block length from pixels (48, "48"), a fraction of the width (0.06, "0.06") or a
    percentage ("6%"). Pixels stay ints so PatchSpec treats them as pixels."""
    if isinstance(value, bool):
        raise SpecError(f"length must be a number, got {value!r}")
    if isinstance(value, int | float):
        return value
    text = str(value).strip()
    try:
        number = float(text[:-1]) / 100.0 if text.endswith("%") else float(text)
        if not math.isfinite(number):  # inf, nan: no length (int() of them is a traceback)
            raise ValueError(text)
    except ValueError:
        raise SpecError(  # noqa: B904 - the ValueError adds nothing to this message
            f"cannot read length {value!r}: use pixels (48), a fraction (0.06) or a percentage (6%)"
        )
    if text.endswith("%"):
        if abs(number) >= 1:  # a length of 1 or more is read as pixels: 200% would have been 2 px
            raise SpecError(f"{text} of the width is no length for the mark: give a percentage under 100%")
        return number
    return int(number) if number.is_integer() and number >= 1 else number


def spec_from_table(table: dict[str, Any], base: PatchSpec | None = None) -> PatchSpec:
    """A PatchSpec from a TOML table, on top of base (default: the product's default_spec()), or on
    top of the named design the table's `design` key names (`ppd poison --design`'s names)."""
    data = dict(table)
    if "design" in data:
        base = _named_design(data.pop("design"))
    for key in ("patch_size", "block_size"):
        if key in data:
            data[key] = parse_length(data[key])
    if "offset" in data:
        data["offset"] = tuple(parse_length(v) if v != 0 else 0 for v in data["offset"])
    known = {f.name for f in dataclasses.fields(PatchSpec)}
    unknown = set(data) - known
    if unknown:
        raise SpecError(f"unknown patch field(s): {', '.join(sorted(unknown))}")
    try:
        spec = (base or default_spec()).replace(**data)
        if problem := mark_problem(spec):  # the user's words: a spec that writes nothing is refused
            raise SpecError(problem)
        return spec
    except SpecError as exc:
        if base is None and "lanes" not in data and {"motion", "pattern", "offset"} & set(data):
            # fields written for the old default (the roaming square) on today's default (two lanes)
            raise SpecError(f'{exc}; to change another design\'s fields, name it: design = "roaming" '
                            '(the moving square) or "paper"') from None
        raise


def mark_problem(spec: PatchSpec) -> str | None:
    """Why spec writes no texture on any photo (it was called "patched": a black-box review), or None.
    Asked where the user makes a spec (spec_from_table), not of a stored one: it stays readable."""
    if round(255 * spec.alpha) == 0:
        return f"alpha {spec.alpha} writes no mark (it blends in less than one level of 255)"
    if spec.ratio == 0:
        return "ratio 0 gives no photo the mark"
    return "contrast 0 makes the mark one flat colour: no texture" if spec.contrast == 0 else None


def _named_design(name: Any) -> PatchSpec:
    specs = design_specs()
    if name not in specs:
        raise SpecError(f"design: unknown {name!r}; choose one of {', '.join(specs)}")
    return specs[name]


# ---- sections -------------------------------------------------------------------------------------
class Section(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """A config table: typed, immutable, unknown keys refused."""


class VerificationSchedule(Section, frozen=True):
    enabled: bool = True
    every_new_files: int = 20
    period_hours: float = 24.0
    # The headline verdict counts every one of them, masked included (verifier.verdict.HEADLINE_PROFILES).
    # A config that lists its profiles keeps its list.
    profiles: tuple[Profile, ...] = ("default", "hardened", "published", "global", "masked")
    splat: bool = False  # scheduled runs include Verifier II's splat stage
    splat_budget_s: float = 150.0
    seeds: int = 1  # the attacker's COLMAP runs per profile: seeds 0..seeds-1, the weakest counts
    keep_runs: int = 5  # run folders kept per dataset (daemon.verification.verify prunes the older ones)

    def __post_init__(self) -> None:
        if why := seeds_problem(self.seeds):  # a bool or a float never gets here (msgspec: an int)
            raise ConfigError(f"seeds {why}")
        if isinstance(self.keep_runs, bool) or not isinstance(self.keep_runs, int) or self.keep_runs < 1:
            raise ConfigError(f"keep_runs must be a whole number >= 1, got {self.keep_runs!r}")
        if self.every_new_files < 1:
            raise ConfigError(f"every_new_files must be >= 1, got {self.every_new_files}")
        msgspec.structs.force_setattr(self, "profiles", tuple(self.profiles))


class VaultConfig(Section, frozen=True):
    max_bytes: int = 0  # 0 = unlimited

    def __post_init__(self) -> None:
        if self.max_bytes < 0:
            raise ConfigError(f"max_bytes must be >= 0 (0: unlimited), got {self.max_bytes}")


class PrivacyConfig(Section, frozen=True):
    keep_location: bool = False  # true: patched files keep GPS/place metadata


class DaemonConfig(Section, frozen=True):
    quarantine_dir: Path | None = None  # None: Config.quarantine_dir_for's default
    # A writer that appends in bursts: the quiet time after a close doubles while the file keeps
    # changing, up to this; and a file whose structure is incomplete is waited for (re-checked)
    # until it has not changed for incomplete_wait_seconds, only then quarantined.
    max_debounce_seconds: float = 30.0
    incomplete_wait_seconds: float = 120.0

    def __post_init__(self) -> None:
        if self.max_debounce_seconds < 0 or self.incomplete_wait_seconds < 0:
            raise ConfigError("max_debounce_seconds and incomplete_wait_seconds must be >= 0")


class LimitsConfig(Section, frozen=True):
    max_megapixels: float = 80.0  # poisoner.limits.DEFAULT_MAX_PIXELS, measured
    max_memory_mb: float = 1024.0  # poisoner.limits.DEFAULT_MAX_PEAK_BYTES: per file, and all workers at once

    def __post_init__(self) -> None:
        if not self.max_memory_mb > 0:
            raise ConfigError(f"max_memory_mb must be a positive number, got {self.max_memory_mb!r}")
        if not self.max_megapixels > 0:
            raise ConfigError(f"max_megapixels must be a positive number, got {self.max_megapixels!r}")


class DatasetOverride(Section, frozen=True, omit_defaults=True):
    """[datasets.NAME]: overrides applied when the dataset gets its spec."""

    spec: str = ""  # "auto": automatic mode picks the patch (docs/AUTO.md); "" = not automatic
    publish_dir: Path | None = None
    subject_masks: Path | None = None  # a folder of subject masks (daemon.datasets.subject_masks)
    patch: dict[str, Any] = {}  # fields replaced on the default spec

    def __post_init__(self) -> None:
        # subject_masks is not checked here: a folder not there (an unplugged drive) is that dataset's
        # state, said and waited for when its files come (daemon.datasets.subject_masks), not a bad
        # config that stopped every command and the daemon
        if self.spec not in ("", AUTO_SPEC):
            raise ConfigError(f'spec must be "{AUTO_SPEC}" (patch fields go in the dataset\'s [patch] table)')
        if self.auto and self.patch:
            raise ConfigError(f'spec = "{AUTO_SPEC}" and a [patch] table exclude each other')

    @property
    def auto(self) -> bool:
        return self.spec == AUTO_SPEC


# ---- the whole file -------------------------------------------------------------------------------
class Config(msgspec.Struct, frozen=True, dict=True, forbid_unknown_fields=True):
    """config.toml, table by table. Field names are the TOML keys."""

    workers: int = 2
    debounce_seconds: float = 2.0
    publish_dir: Path | None = None
    patch: dict[str, Any] = {}  # fields replaced on default_spec(); `spec` is the result
    verification: VerificationSchedule = msgspec.field(default_factory=VerificationSchedule)
    vault: VaultConfig = msgspec.field(default_factory=VaultConfig)
    privacy: PrivacyConfig = msgspec.field(default_factory=PrivacyConfig)
    daemon: DaemonConfig = msgspec.field(default_factory=DaemonConfig)
    limits: LimitsConfig = msgspec.field(default_factory=LimitsConfig)
    visibility: VisibilityBudget = msgspec.field(default_factory=VisibilityBudget)
    preflight: PreflightOptions = msgspec.field(default_factory=PreflightOptions)
    datasets: dict[str, DatasetOverride] = {}
    source: ClassVar[Path | None] = None  # the file it was read from (set by from_toml; not a key)

    def __post_init__(self) -> None:
        if self.workers < 1:
            raise ConfigError(f"workers must be >= 1, got {self.workers}")
        if self.debounce_seconds < 0:
            raise ConfigError(f"debounce_seconds must be >= 0, got {self.debounce_seconds}")
        try:
            base = self.spec
        except SpecError as exc:
            raise ConfigError(f"[patch] {exc}") from None
        for name, override in self.datasets.items():
            try:  # validate now, not when the first file arrives
                spec_from_table(override.patch, base)
            except SpecError as exc:
                raise ConfigError(f"[datasets.{name}.patch] {exc}") from None

    # ---- loading --------------------------------------------------------------------------
    @classmethod
    def load(cls, paths: AppPaths) -> Config:
        """The config at paths.config_file, or the defaults when there is none."""
        file = paths.config_file
        if not file.exists():
            return cls()
        try:
            text = file.read_text(encoding="utf-8")
        except OSError as exc:
            raise ConfigError(f"cannot read {file}: {exc.strerror}") from exc
        return cls.from_toml(text, source=file)

    @classmethod
    def from_toml(cls, text: str, source: Path | None = None) -> Config:
        """A Config from TOML text; a bad value raises ConfigError naming the file and the key."""
        where = str(source) if source else "config"
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{where}: {exc}") from exc
        if old := [k for k in _OLD_BUDGET_KEYS if k in data.get("visibility", {})]:
            raise ConfigError(
                f"{where}: visibility.{old[0]}: the visibility budget is now what a viewer sees (FLIP): "
                "set max_noticeable_area, max_p999_vs_jpeg, corner_only (SSIM/LPIPS are reported only)"
            )
        data = _unset_empty(data)
        datasets = data.get("datasets", {})
        for name, table in datasets.items() if isinstance(datasets, dict) else ():
            _convert(table, DatasetOverride, where, f"datasets.{name}")  # msgspec's path omits the name
        config = _convert(data, cls, where, "")
        config.__dict__["source"] = source
        return config

    # ---- flat views callers use -------------------------------------------------------------
    @functools.cached_property
    def spec(self) -> PatchSpec:
        """The default spec with [patch]'s fields replaced."""
        return spec_from_table(self.patch)

    @property
    def keep_location(self) -> bool:
        return self.privacy.keep_location

    @property
    def quarantine_dir(self) -> Path | None:
        return self.daemon.quarantine_dir

    @property
    def max_megapixels(self) -> float:
        return self.limits.max_megapixels

    @property
    def max_pixels(self) -> int:
        """[limits] max_megapixels in pixels, as poisoner.limits takes it."""
        return int(self.limits.max_megapixels * 1_000_000)

    @property
    def max_memory_bytes(self) -> int:
        """[limits] max_memory_mb in bytes (poisoner.limits.peak_bytes's unit)."""
        return int(self.limits.max_memory_mb * 1_000_000)

    # ---- per dataset ----------------------------------------------------------------------
    def is_auto(self, dataset: str) -> bool:
        """Whether the dataset is in automatic mode (`spec = "auto"`)."""
        override = self.datasets.get(dataset)
        return bool(override and override.auto)

    def spec_for(self, dataset: str) -> PatchSpec:
        """The spec a new dataset gets: the default with its [datasets.NAME.patch] overrides.

        An automatic dataset starts on the interim spec (poisoner.ladder.strongest_spec: the ladder's
        strongest candidate, replaced within the budget once files are measured); "auto" itself
        never reaches the poisoner."""
        override = self.datasets.get(dataset)
        if override and override.auto:
            return strongest_spec()
        return spec_from_table(override.patch, self.spec) if override and override.patch else self.spec

    def position_set(self, dataset: str) -> bool:
        """Whether the user chose where the mark goes ([patch] or [datasets.NAME.patch] position):
        a corner mark's corner is then theirs, not chosen per dataset (daemon.datasets.subject_masks)."""
        override = self.datasets.get(dataset)
        return "position" in self.patch or bool(override and "position" in override.patch)

    def subject_masks_for(self, dataset: str) -> Path | None:
        """[datasets.NAME] subject_masks: the dataset's folder of subject masks, or None."""
        override = self.datasets.get(dataset)
        return override.subject_masks if override is not None else None

    def quarantine_dir_for(self, outbox: Path) -> Path:
        """Where the daemon moves files it cannot patch: [daemon] quarantine_dir, else a visible
        folder next to the outbox (outside it, so nothing there is published or watched)."""
        if self.daemon.quarantine_dir is not None:
            return self.daemon.quarantine_dir
        return Path(outbox).absolute().parent / "ppd-quarantine"

    def publish_dir_for(self, dataset: str) -> Path | None:
        override = self.datasets.get(dataset)
        if override and override.publish_dir is not None:
            return override.publish_dir
        return self.publish_dir / dataset if self.publish_dir is not None else None

    # ---- writing --------------------------------------------------------------------------
    def to_toml(self) -> str:
        """The effective configuration as TOML (what `ppd config show` prints); reads back equal."""
        data = msgspec.to_builtins(self, enc_hook=_encode_path)
        data["patch"] = self.spec.to_dict()  # the effective spec, not only the replaced fields
        if not data["datasets"]:
            del data["datasets"]
        return msgspec.toml.encode(_none_as_empty(data)).decode()


def _convert(data: Any, kind: type[msgspec.Struct], where: str, path: str) -> Any:
    """msgspec.convert with a ConfigError naming the file and the key path on a bad value."""
    try:
        return msgspec.convert(data, kind, dec_hook=_decode_path)
    except msgspec.ValidationError as exc:
        message = _validation_message(exc, path)
        if (choices := _choices_for(exc, kind)) is not None:  # "invalid enum value 'hardend'" said no more
            message += f" (one of: {', '.join(map(str, choices))})"
        raise ConfigError(f"{where}: {message}") from None


def _choices_for(exc: msgspec.ValidationError, kind: type[msgspec.Struct]) -> tuple[Any, ...] | None:
    """The values a bad enum value could have been, from the schema at the error's key path; None for
    another error, or a path not followed (a fifth black-box review: `profiles = ["hardend"]` was
    refused without the names, where `[patch] design` lists them)."""
    import msgspec.inspect as mi

    match = re.fullmatch(r"Invalid enum value .* - at `\$(.*)`", str(exc).splitlines()[0])
    if not match:
        return None
    info: Any = mi.type_info(kind)
    for name, index in re.findall(r"\.([^.\[]+)|\[(\d+)\]", match.group(1)):
        if isinstance(info, mi.UnionType):  # an optional table: its non-None member
            info = next((t for t in info.types if not isinstance(t, mi.NoneType)), info)
        if name and isinstance(info, mi.StructType):
            info = next((f.type for f in info.fields if f.encode_name == name), None)
        elif name and isinstance(info, mi.DictType):
            info = info.value_type
        elif index and isinstance(info, (mi.ListType, mi.VarTupleType, mi.SetType, mi.FrozenSetType)):
            info = info.item_type
        else:
            return None
    if isinstance(info, mi.LiteralType):
        return tuple(info.values)
    if isinstance(info, mi.EnumType):
        return tuple(m.value for m in info.cls)
    return None


def _decode_path(kind: type, value: Any) -> Any:
    if kind is Path and isinstance(value, str):
        return Path(value).expanduser()
    raise TypeError(f"expected a folder path (a string), got {type(value).__name__}")


def _encode_path(value: Any) -> Any:
    if isinstance(value, Path):
        return str(value)
    raise NotImplementedError  # msgspec's enc_hook protocol: "this type is not supported"


def _unset_empty(table: dict[str, Any]) -> dict[str, Any]:
    """The TOML data with `folder = ""` left out (its default: not set), at every depth."""
    return {
        k: _unset_empty(v) if isinstance(v, dict) else v
        for k, v in table.items()
        if not (k in _EMPTY_MEANS_UNSET and v == "")
    }


def _none_as_empty(value: Any) -> Any:
    """TOML has no null: an unset optional is written as "" (which reads back as unset)."""
    if isinstance(value, dict):
        return {k: _none_as_empty(v) for k, v in value.items()}
    return "" if value is None else value


def _validation_message(exc: msgspec.ValidationError, prefix: str) -> str:
    """msgspec's "Expected `int` >= 1 - at `$.verification.keep_runs`" as "verification.keep_runs:
    expected `int` >= 1" (one line, the key path first)."""
    text = str(exc).splitlines()[0].replace("Object contains unknown field", "unknown key")
    match = re.fullmatch(r"(.*) - at `\$\.?(.*)`", text)
    if not match:
        text = text[:1].lower() + text[1:]
        return f"{prefix}: {text}" if prefix else text
    what, path = match.groups()
    what = what[:1].lower() + what[1:]
    path = ".".join(p for p in (prefix, path) if p)
    return f"{path}: {what}" if path else what
