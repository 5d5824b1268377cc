"""ppd's configuration: typed dataclasses loaded from `config_dir/config.toml`.

Every key is optional; what is missing comes from the embedded defaults below. Layout:

    workers = 2                 # concurrent protect jobs in the daemon
    debounce_seconds = 2.0      # quiet time before a changed file is processed
    publish_dir = ""            # optional: protected files are moved here ("" = stay in the outbox)

    [patch]                     # fields replaced on the default spec; sizes: 48, 0.06 or "6%"
    patch_size = 0.06           # default: poisoner.ladder.default_spec(), a non-repetitive texture
                                # of 6% of the width moving 0.75% per image (docs/DESIGNS.md);
                                # the paper's static checkerboard: pattern = "checkerboard",
                                # offset = [0, 0], motion = "static"

    [verification]
    enabled = true
    every_new_files = 20        # verify a dataset after this many newly protected files
    period_hours = 24.0         # ... and at least this often while it keeps changing
    profiles = ["default", "hardened", "published"]
    splat = false               # also train clean/poisoned Gaussian splats (~6 more minutes per 40 views)
    splat_budget_s = 150.0      # splat training seconds per side
    keep_runs = 5               # run folders (SfM models) kept per dataset; older ones are deleted

    [vault]
    max_bytes = 0               # 0 = unlimited; when full, protection is refused (never silent deletion)

    [privacy]
    keep_location = false       # true: patched files keep GPS/place metadata (default: removed)

    [daemon]
    quarantine_dir = ""         # files `ppd watch` cannot patch go here ("": <outbox>/../ppd-quarantine)

    [limits]
    max_megapixels = 80.0       # larger images are refused before decoding (WebP: a fifth, HEIF: a third)

    [visibility]                # automatic mode's budget, clean vs poisoned, whole image
    min_ssim = 0.99
    max_lpips = 0.02

    [preflight]                 # automatic mode's check on a sample of the dataset (docs/AUTO.md)
    sample_size = 12
    time_budget_s = 900.0
    profiles = ["default", "hardened"]

    [datasets.NAME]             # per-dataset overrides, applied when the dataset gets its spec
    publish_dir = "/srv/www/NAME"
    spec = "auto"               # automatic mode: the verifier picks the patch (docs/AUTO.md)
    [datasets.NAME.patch]
    position = "bottom-right"
"""

from __future__ import annotations

import dataclasses
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from daemon.paths import AppPaths
from poisoner.ladder import default_spec, strongest_spec
from poisoner.spec import PatchSpec, SpecError


class ConfigError(ValueError):
    """config.toml cannot be read or holds an invalid value (message = one line)."""


def parse_length(value: Any) -> int | float:
    """A patch/block length from pixels (48, "48"), a fraction of the width (0.06, "0.06") or a
    percentage ("6%"). Pixels stay ints so PatchSpec treats them as pixels."""
    if isinstance(value, bool):
        raise SpecError(f"length must be a number, got {value!r}")
    if isinstance(value, int | float):
        return value
    text = str(value).strip()
    try:
        if text.endswith("%"):
            return float(text[:-1]) / 100.0
        number = float(text)
    except ValueError:
        raise SpecError(  # noqa: B904 - the ValueError adds nothing to this message
            f"cannot read length {value!r}: use pixels (48), a fraction (0.06) or a percentage (6%)"
        )
    return int(number) if number.is_integer() and number >= 1 else number


def spec_from_table(table: dict[str, Any], base: PatchSpec | None = None) -> PatchSpec:
    """A PatchSpec from a TOML table, on top of base (default: the product's default_spec())."""
    data = dict(table)
    for key in ("patch_size", "block_size"):
        if key in data:
            data[key] = parse_length(data[key])
    if "offset" in data:
        data["offset"] = tuple(parse_length(v) if v != 0 else 0 for v in data["offset"])
    known = {f.name for f in dataclasses.fields(PatchSpec)}
    unknown = set(data) - known
    if unknown:
        raise SpecError(f"unknown patch field(s): {', '.join(sorted(unknown))}")
    return (base or default_spec()).replace(**data)


@dataclass(frozen=True)
class VerificationSchedule:
    enabled: bool = True
    every_new_files: int = 20
    period_hours: float = 24.0
    profiles: tuple[str, ...] = ("default", "hardened", "published")
    splat: bool = False  # scheduled runs include Verifier II's splat stage
    splat_budget_s: float = 150.0
    keep_runs: int = 5  # run folders kept per dataset (daemon.verify prunes the older ones)

    def __post_init__(self) -> None:
        if isinstance(self.keep_runs, bool) or not isinstance(self.keep_runs, int) or self.keep_runs < 1:
            raise ConfigError(f"verification.keep_runs must be a whole number >= 1, got {self.keep_runs!r}")


@dataclass(frozen=True)
class VaultConfig:
    max_bytes: int = 0  # 0 = unlimited


@dataclass(frozen=True)
class VisibilityConfig:
    """Automatic mode's visibility budget (verifier.auto.VisibilityBudget's values)."""

    min_ssim: float = 0.99
    max_lpips: float = 0.02

    def __post_init__(self) -> None:
        if not 0.0 < float(self.min_ssim) <= 1.0:
            raise ConfigError(f"visibility.min_ssim must be in (0, 1], got {self.min_ssim}")
        if float(self.max_lpips) < 0.0:
            raise ConfigError(f"visibility.max_lpips must be >= 0, got {self.max_lpips}")


@dataclass(frozen=True)
class PreflightConfig:
    """Automatic mode's preflight (verifier.auto.PreflightOptions' values)."""

    sample_size: int = 12
    time_budget_s: float = 900.0
    profiles: tuple[str, ...] = ("default", "hardened")

    def __post_init__(self) -> None:
        if int(self.sample_size) < 3:
            raise ConfigError(f"preflight.sample_size must be at least 3, got {self.sample_size}")
        if float(self.time_budget_s) <= 0:
            raise ConfigError(f"preflight.time_budget_s must be positive, got {self.time_budget_s}")


AUTO_SPEC = "auto"  # `spec = "auto"` in [datasets.NAME]


@dataclass(frozen=True)
class DatasetOverride:
    patch: dict[str, Any] = field(default_factory=dict)  # fields replaced on the default spec
    publish_dir: Path | None = None
    auto: bool = False  # spec = "auto": automatic mode picks the patch (docs/AUTO.md)


@dataclass(frozen=True)
class Config:
    spec: PatchSpec = field(default_factory=default_spec)
    workers: int = 2
    debounce_seconds: float = 2.0
    publish_dir: Path | None = None
    verification: VerificationSchedule = field(default_factory=VerificationSchedule)
    vault: VaultConfig = field(default_factory=VaultConfig)
    datasets: dict[str, DatasetOverride] = field(default_factory=dict)
    visibility: VisibilityConfig = field(default_factory=VisibilityConfig)
    preflight: PreflightConfig = field(default_factory=PreflightConfig)
    keep_location: bool = False  # [privacy] keep_location
    quarantine_dir: Path | None = None  # [daemon] quarantine_dir (None: quarantine_dir_for's default)
    max_megapixels: float = 80.0  # [limits] max_megapixels: poisoner.limits.DEFAULT_MAX_PIXELS, measured
    source: Path | None = None  # the file it was read from, if any

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
        where = str(source) if source else "config"
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{where}: {exc}") from exc
        try:
            return cls._from_dict(data, source)
        except (SpecError, TypeError, ValueError) as exc:
            raise ConfigError(f"{where}: {str(exc).splitlines()[0]}") from exc

    @classmethod
    def _from_dict(cls, data: dict[str, Any], source: Path | None) -> Config:
        known = {
            "workers", "debounce_seconds", "publish_dir", "patch", "verification", "vault", "datasets",
            "visibility", "preflight", "privacy", "daemon", "limits",
        }  # fmt: skip
        unknown = set(data) - known
        if unknown:
            raise ConfigError(f"unknown key(s): {', '.join(sorted(unknown))}")
        spec = spec_from_table(data.get("patch", {}))
        ver = dict(data.get("verification", {}))
        if "profiles" in ver:
            ver["profiles"] = tuple(ver["profiles"])
        datasets: dict[str, DatasetOverride] = {}
        for name, table in data.get("datasets", {}).items():
            patch = dict(table.get("patch", {}))
            spec_from_table(patch, spec)  # validate now, not when the first file arrives
            datasets[name] = DatasetOverride(
                patch=patch,
                publish_dir=_optional_path(table.get("publish_dir")),
                auto=_auto_flag(name, table),
            )
        preflight = dict(data.get("preflight", {}))
        if "profiles" in preflight:
            preflight["profiles"] = tuple(preflight["profiles"])
        privacy, daemon_table = dict(data.get("privacy", {})), dict(data.get("daemon", {}))
        limits = dict(data.get("limits", {}))
        for table, allowed, name in (
            (privacy, {"keep_location"}, "privacy"),
            (daemon_table, {"quarantine_dir"}, "daemon"),
            (limits, {"max_megapixels"}, "limits"),
        ):
            if extra := set(table) - allowed:
                raise ConfigError(f"unknown key(s) in [{name}]: {', '.join(sorted(extra))}")
        if not isinstance(privacy.get("keep_location", False), bool):
            raise ConfigError("privacy.keep_location must be true or false")
        max_mp = limits.get("max_megapixels", 80.0)
        if isinstance(max_mp, bool) or not isinstance(max_mp, int | float) or max_mp <= 0:
            raise ConfigError(f"limits.max_megapixels must be a positive number, got {max_mp!r}")
        workers = int(data.get("workers", 2))
        if workers < 1:
            raise ConfigError(f"workers must be >= 1, got {workers}")
        return cls(
            spec=spec,
            workers=workers,
            debounce_seconds=float(data.get("debounce_seconds", 2.0)),
            publish_dir=_optional_path(data.get("publish_dir")),
            verification=VerificationSchedule(**ver),
            vault=VaultConfig(**data.get("vault", {})),
            datasets=datasets,
            visibility=VisibilityConfig(**data.get("visibility", {})),
            preflight=PreflightConfig(**preflight),
            keep_location=privacy.get("keep_location", False),
            quarantine_dir=_optional_path(daemon_table.get("quarantine_dir")),
            max_megapixels=float(max_mp),
            source=source,
        )

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

    @property
    def max_pixels(self) -> int:
        """[limits] max_megapixels in pixels, as poisoner.limits takes it."""
        return int(self.max_megapixels * 1_000_000)

    def quarantine_dir_for(self, outbox: Path) -> Path:
        """Where the daemon moves files it cannot patch: [daemon] quarantine_dir, else a visible
        folder next to the outbox (outside it, so nothing there is published or watched)."""
        if self.quarantine_dir is not None:
            return self.quarantine_dir
        return Path(outbox).absolute().parent / "ppd-quarantine"

    def publish_dir_for(self, dataset: str) -> Path | None:
        override = self.datasets.get(dataset)
        if override and override.publish_dir is not None:
            return override.publish_dir
        return self.publish_dir / dataset if self.publish_dir is not None else None

    # ---- writing --------------------------------------------------------------------------
    def to_toml(self) -> str:
        """The effective configuration as TOML (what `ppd config show` prints)."""
        lines = [
            f"workers = {self.workers}",
            f"debounce_seconds = {self.debounce_seconds!r}",
            f"publish_dir = {_toml_value(str(self.publish_dir) if self.publish_dir else '')}",
            "",
            "[patch]",
        ]
        lines += [f"{k} = {_toml_value(v)}" for k, v in self.spec.to_dict().items()]
        lines += ["", "[verification]"]
        lines += [f"{k} = {_toml_value(v)}" for k, v in dataclasses.asdict(self.verification).items()]
        lines += ["", "[vault]", f"max_bytes = {self.vault.max_bytes}"]
        lines += ["", "[privacy]", f"keep_location = {_toml_value(self.keep_location)}"]
        lines += ["", "[daemon]", f"quarantine_dir = {_toml_value(str(self.quarantine_dir or ''))}"]
        lines += ["", "[limits]", f"max_megapixels = {self.max_megapixels!r}"]
        lines += ["", "[visibility]"]
        lines += [f"{k} = {_toml_value(v)}" for k, v in dataclasses.asdict(self.visibility).items()]
        lines += ["", "[preflight]"]
        lines += [f"{k} = {_toml_value(v)}" for k, v in dataclasses.asdict(self.preflight).items()]
        for name, override in sorted(self.datasets.items()):
            lines += ["", f"[datasets.{_toml_key(name)}]"]
            if override.auto:
                lines.append(f"spec = {_toml_value(AUTO_SPEC)}")
            if override.publish_dir is not None:
                lines.append(f"publish_dir = {_toml_value(str(override.publish_dir))}")
            if override.patch:
                lines += ["", f"[datasets.{_toml_key(name)}.patch]"]
                lines += [f"{k} = {_toml_value(v)}" for k, v in override.patch.items()]
        return "\n".join(lines) + "\n"


def _auto_flag(name: str, table: dict[str, Any]) -> bool:
    """`spec = "auto"` (the only value `spec` takes; a concrete patch goes in [datasets.NAME.patch])."""
    if "spec" not in table:
        return False
    if table["spec"] != AUTO_SPEC:
        raise ConfigError(
            f'datasets.{name}.spec must be "{AUTO_SPEC}" (set patch fields in [datasets.{name}.patch])'
        )
    if table.get("patch"):
        raise ConfigError(f'datasets.{name}: spec = "{AUTO_SPEC}" and a [patch] table exclude each other')
    return True


def _optional_path(value: Any) -> Path | None:
    return Path(str(value)).expanduser() if value else None


def _toml_key(key: str) -> str:
    bare = key.replace("-", "").replace("_", "").isalnum() and key.isascii()
    return key if bare else _toml_value(key)


def _toml_value(value: Any) -> str:
    """A TOML literal for the scalar/list values this config holds."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    text = str(value).replace("\\", "\\\\").replace('"', '\\"')
    return f'"{text}"'
