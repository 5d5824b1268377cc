"""daemon.config: the typed schema (msgspec structs), its one-line errors with the key path, the
FLIP visibility budget shared with the verifier, and the TOML it writes back."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any, cast

import msgspec
import pytest

from daemon.config import Config, ConfigError
from poisoner.ladder import default_spec
from verifier.auto_options import PreflightOptions, VisibilityBudget


def test_config_reads_auto_datasets_budget_and_preflight() -> None:
    cfg = Config.from_toml(
        """
        workers = 3
        [patch]
        patch_size = 48
        [visibility]
        max_noticeable_area = 0.005
        max_p999_vs_jpeg = 2.5
        corner_only = true
        [preflight]
        sample_size = 8
        time_budget_s = 300
        profiles = ["default"]
        [datasets.trip]
        spec = "auto"
        publish_dir = "/tmp/pub"
        [datasets.fixed.patch]
        position = "bottom-right"
        """
    )
    assert cfg.is_auto("trip") and not cfg.is_auto("fixed") and not cfg.is_auto("other")
    wanted = VisibilityBudget(max_noticeable_area=0.005, max_p999_vs_jpeg=2.5, corner_only=True)
    assert cfg.visibility == wanted
    assert cfg.preflight.sample_size == 8 and cfg.preflight.profiles == ("default",)
    assert cfg.preflight.time_budget_s == 300.0 and isinstance(cfg.preflight.time_budget_s, float)
    assert cfg.workers == 3 and cfg.spec.patch_size == 48  # existing keys still work
    assert cfg.spec_for("fixed").position == "bottom-right"
    assert cfg.publish_dir_for("trip") == Path("/tmp/pub")
    again = Config.from_toml(cfg.to_toml())  # `ppd config show` output reads back the same
    assert again.is_auto("trip") and again.visibility == cfg.visibility and again.preflight == cfg.preflight
    assert again.datasets == cfg.datasets and again.spec == cfg.spec


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ('[datasets.t]\nspec = "magic"', 'datasets.t: spec must be "auto"'),
        ('[datasets.t]\nspec = "auto"\n[datasets.t.patch]\npatch_size = 48', 'datasets.t: spec = "auto" and'),
        ("[datasets.t.patch]\nsize = 48", "[datasets.t.patch] unknown patch field(s): size"),
        ("[visibility]\nmax_noticeable_area = 1.5", "visibility: max_noticeable_area must be"),
        ("[visibility]\ncorner_only = 1", "visibility.corner_only: expected `bool`, got `int`"),
        ("[preflight]\nsample_size = 2", "preflight: sample_size must be at least 3"),
        ('[preflight]\nprofiles = ["hardend"]', "preflight.profiles[0]: invalid enum value 'hardend'"),
        # the names, as `[patch] design` lists its own (a fifth black-box review)
        ('[verification]\nprofiles = ["default", "hardend"]',
         "verification.profiles[1]: invalid enum value 'hardend' (one of: default, global, hardened, masked, "
         "published)"),
        ('[verification]\nkeep_runs = "3"', "verification.keep_runs: expected `int`, got `str`"),
        ("[privacy]\nkeep_location = 1", "privacy.keep_location: expected `bool`"),
        ("[limits]\nmax_megapixels = -1", "limits: max_megapixels must be a positive number"),
        ("[daemon]\nquarantine_dir = 3", "daemon.quarantine_dir: expected a folder path"),
        ("[vault]\nmax_bytez = 3", "vault: unknown key `max_bytez`"),
        ("workers = 0", "workers must be >= 1"),
        ("workers = [", "config.toml: "),  # not TOML at all
    ],
)
def test_bad_config_is_one_line_naming_the_file_and_the_key(text: str, needle: str) -> None:
    with pytest.raises(ConfigError) as info:
        Config.from_toml(text, source=Path("/home/me/.config/ppd/config.toml"))
    message = str(info.value)
    assert message.startswith("/home/me/.config/ppd/config.toml: ") and needle in message, message
    assert "\n" not in message


def test_the_old_ssim_budget_is_refused_with_what_replaces_it() -> None:
    with pytest.raises(ConfigError, match=r"visibility.min_ssim: .*FLIP.*max_noticeable_area") as info:
        Config.from_toml("[visibility]\nmin_ssim = 0.99\nmax_lpips = 0.02\n")
    assert "\n" not in str(info.value)


def test_defaults_have_one_source() -> None:
    """The config's [visibility] and [preflight] are the verifier's own structs, with its defaults."""
    cfg = Config()
    assert cfg.visibility == VisibilityBudget() and cfg.preflight == PreflightOptions()
    assert type(cfg.visibility) is VisibilityBudget and type(cfg.preflight) is PreflightOptions
    assert (cfg.visibility.max_noticeable_area, cfg.visibility.max_p999_vs_jpeg) == (0.01, 0.0)
    assert not cfg.visibility.corner_only and cfg.visibility.display_width == 1920
    assert cfg.spec == default_spec() and cfg.source is None and not cfg.is_auto("anything")
    assert (cfg.keep_location, cfg.quarantine_dir, cfg.max_pixels) == (False, None, 80_000_000)
    assert Config.from_toml("") == cfg


def test_display_width_matches_the_visibility_module() -> None:
    from verifier import auto_options, visibility

    assert auto_options.DISPLAY_WIDTH == visibility.DISPLAY_WIDTH


def test_empty_folder_means_unset_and_source_is_not_a_key(tmp_path: Path) -> None:
    text = 'publish_dir = ""\n[daemon]\nquarantine_dir = ""\n[preflight]\ncamera_params = ""\n'
    cfg = Config.from_toml(text, source=tmp_path / "config.toml")
    assert cfg.publish_dir is None and cfg.quarantine_dir is None and cfg.preflight.camera_params is None
    assert cfg.source == tmp_path / "config.toml"
    with pytest.raises(ConfigError, match="unknown key `source`"):
        Config.from_toml('source = "/etc/passwd"\n')
    home = Config.from_toml('publish_dir = "~/pub"\n')
    assert home.publish_dir == Path.home() / "pub"


def test_to_toml_is_written_by_the_schema_and_reads_back_equal() -> None:
    cfg = Config.from_toml(
        'publish_dir = "/srv/www"\n[privacy]\nkeep_location = true\n[limits]\nmax_megapixels = 12.5\n'
        '[datasets."my trip"]\nspec = "auto"\n[datasets.b]\npublish_dir = "/b"\n'
        '[datasets.b.patch]\nposition = "bottom-right"\n'
    )
    text = cfg.to_toml()
    assert '[datasets."my trip"]' in text and 'quarantine_dir = ""' in text and "keep_location = true" in text
    again = Config.from_toml(text)
    for attr in ("publish_dir", "verification", "vault", "privacy", "daemon", "limits", "visibility",
                 "preflight", "datasets", "spec"):  # fmt: skip
        assert getattr(again, attr) == getattr(cfg, attr), attr
    assert again.spec_for("b") == cfg.spec_for("b") and again.max_pixels == 12_500_000


def test_sections_are_frozen() -> None:
    cfg = cast(Any, Config())  # the assignments a type checker refuses: is the refusal real at run time?
    with pytest.raises(AttributeError):
        cfg.workers = 5
    with pytest.raises(AttributeError):
        cfg.visibility.corner_only = True
    assert msgspec.structs.replace(cfg.visibility, corner_only=True).corner_only  # how callers override


def test_importing_the_config_stays_light() -> None:
    """`ppd status` starts by reading the config: no numpy, PIL or flip_evaluator on the way."""
    heavy = "('numpy', 'PIL', 'flip_evaluator', 'torch')"
    code = f"import sys, daemon.config; print(sorted(m for m in {heavy} if m in sys.modules))"
    root = Path(__file__).resolve().parents[2]
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=root)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr


def test_subject_masks_per_dataset_and_a_missing_folder_is_no_config_error(tmp_path: Path) -> None:
    """A folder not there (a drive unplugged) is that dataset's state, said when its files come
    (daemon.datasets.subject_masks.MaskFolderMissing): it stopped every command at load (s5 F4)."""
    masks = tmp_path / "masks"
    masks.mkdir()
    text = f'[datasets.lego]\nsubject_masks = "{masks}"\n[datasets.other]\nsubject_masks = ""\n'
    cfg = Config.from_toml(text)
    assert cfg.subject_masks_for("lego") == masks
    assert cfg.subject_masks_for("other") is None and cfg.subject_masks_for("unknown") is None  # "" = unset
    gone = Config.from_toml(f'[datasets.lego]\nsubject_masks = "{tmp_path / "gone"}"\n')
    assert gone.subject_masks_for("lego") == tmp_path / "gone"


def test_position_set_says_whether_the_user_chose_the_corner() -> None:
    assert not Config().position_set("lego")
    assert Config.from_toml('[patch]\nposition = "top-right"\n').position_set("lego")
    per_dataset = Config.from_toml('[datasets.lego.patch]\nposition = "bottom-left"\n')
    assert per_dataset.position_set("lego") and not per_dataset.position_set("other")


def test_masked_is_verified_by_default_and_an_explicit_list_is_kept() -> None:
    assert Config().verification.profiles == ("default", "hardened", "published", "global", "masked")
    old = Config.from_toml('[verification]\nprofiles = ["default", "hardened", "published"]\n')
    assert old.verification.profiles == ("default", "hardened", "published")
