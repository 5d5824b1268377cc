"""What automatic mode's preflight takes: the visibility budget, the preflight options, the job.

The one source of these defaults: the daemon's config sections [visibility] and [preflight] are
these structs (daemon.config), `ppd auto` starts from them, and the preflight child receives them
in its JSON job. Light on purpose (msgspec only): `import daemon.config` must stay fast.

The budget is what a viewer sees (issue 14), not whole-image SSIM: FLIP (verifier.visibility) on the
picture shown `display_width` pixels wide at FLIP's 67 pixels per degree, on the worst image of the
sample. SSIM, PSNR and LPIPS are still measured and reported (the paper's cost2); they do not gate.
"""

from __future__ import annotations

from enum import StrEnum
from typing import Literal

import msgspec

from poisoner.errors import ExitStatus, PpdError
from poisoner.spec import PatchSpec

Profile = Literal["default", "hardened", "published", "global", "masked"]  # verifier.sfm.profile_sfm_settings
DISPLAY_WIDTH = 1920  # verifier.visibility.DISPLAY_WIDTH: a full-HD screen showing the photo full width
# the fewest images a preflight reconstructs from (COLMAP needs three views for a model worth judging)
MIN_SAMPLE = 3


class CandidateStatus(StrEnum):
    """Where one candidate ended in a preflight."""

    OVER_BUDGET = "over_budget"
    PROTECTED = "protected"
    NOT_PROTECTED = "not_protected"  # some profile was weak / not_protected / crashed
    INCONCLUSIVE = "inconclusive"  # the clean reference failed: no claim either way
    NOT_REACHED = "not_reached"  # the time budget ran out before its turn
    TIMED_OUT = "timed_out"  # the time budget ran out during its verification
    NOT_NEEDED = "not_needed"  # a less visible candidate was already confirmed
    FAILED = "failed"  # it could not be applied to this dataset (e.g. does not fit the images)


class Outcome(StrEnum):
    """How a preflight ended."""

    CHOSEN = "chosen"
    NONE_WITHIN_BUDGET = "none_within_budget"
    TIME_BUDGET = "time_budget"
    INCONCLUSIVE = "inconclusive"


class PreflightInputError(PpdError, ValueError):
    """A sample or a setting that cannot be preflighted (message = one clear line)."""

    exit_status = ExitStatus.USAGE


class VisibilityBudget(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """How visible a patch may be, judged on the worst image of the sample as a viewer sees it.

    A candidate fits when its noticeable area (FLIP > 0.5) is at most `max_noticeable_area`, its
    FLIP 99.9th percentile at most `max_p999_vs_jpeg` times that of a JPEG q85 re-encode of the same
    image (0: not gated), and, with `corner_only`, every changed pixel lies in one corner region
    (a mark that looks intentional, like a photographer's signature)."""

    max_noticeable_area: float = 0.01  # fraction of the displayed picture with FLIP > 0.5
    max_p999_vs_jpeg: float = 0.0  # FLIP p99.9 / a JPEG q85 re-encode's; 0 = not gated
    corner_only: bool = False  # true: a watermark-like mark, confined to one corner region
    corner_region: float = 0.2  # a corner region: this fraction of the width by of the height
    display_width: int = DISPLAY_WIDTH  # the viewing condition: pixels across (smaller images: their own)

    def __post_init__(self) -> None:
        if not 0.0 <= self.max_noticeable_area <= 1.0:
            raise PreflightInputError(f"max_noticeable_area must be 0..1, got {self.max_noticeable_area!r}")
        if self.max_p999_vs_jpeg < 0.0:
            raise PreflightInputError(f"max_p999_vs_jpeg must be >= 0 (0: off), got {self.max_p999_vs_jpeg}")
        if not 0.0 < self.corner_region <= 0.5:
            raise PreflightInputError(f"corner_region must be in (0, 0.5], got {self.corner_region}")
        if self.display_width < 8:
            raise PreflightInputError(f"display_width must be at least 8 px, got {self.display_width}")

    def describe(self) -> str:
        """The budget in a creator's words (used in decisions' reasons)."""
        parts = [f"at most {self.max_noticeable_area:.2%} of the picture noticeably changed (FLIP > 0.5)"]
        if self.max_p999_vs_jpeg > 0:
            parts.append(f"FLIP p99.9 <= {self.max_p999_vs_jpeg:g}x a JPEG q85 re-encode's")
        if self.corner_only:
            parts.append(f"inside one corner region ({self.corner_region:.0%} x {self.corner_region:.0%})")
        return ", ".join(parts) + f", seen at most {self.display_width} px wide"


class PreflightOptions(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """How the preflight verifies the candidates within the budget."""

    sample_size: int = 12
    time_budget_s: float = 900.0
    profiles: tuple[Profile, ...] = ("default", "hardened")
    lpips_net: Literal["vgg", "alex", "none"] = "vgg"  # LPIPS is reported, not gated; "none": skipped
    crash_retries: int = 1  # as Verifier I: a crashed SfM is rerun once with another seed
    keep_images: bool = False  # keep each candidate's poisoned sample (inspection)
    # known intrinsics "fx,fy,cx,cy,k1,k2,p1,p2" as Verifier I takes them; None ("" in TOML) = COLMAP
    # estimates the focal length, where pycolmap 4.2.1 can segfault on poisoned sets (a crash)
    camera_params: str | None = None

    def __post_init__(self) -> None:
        if self.sample_size < 3:
            raise PreflightInputError(f"sample_size must be at least 3 (SfM), got {self.sample_size}")
        if self.time_budget_s <= 0:
            raise PreflightInputError(f"time_budget_s must be positive, got {self.time_budget_s}")
        if self.crash_retries < 0:
            raise PreflightInputError(f"crash_retries must be >= 0, got {self.crash_retries}")
        # callers may pass a list; TOML has no null, so "" means "not given"
        msgspec.structs.force_setattr(self, "profiles", tuple(self.profiles))
        if self.camera_params == "":
            msgspec.structs.force_setattr(self, "camera_params", None)


class LadderEntry(msgspec.Struct, frozen=True):
    """A ladder candidate as a job carries it (same fields as poisoner.ladder.Candidate)."""

    name: str
    spec: PatchSpec
    why: str = ""


class PreflightJob(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """What the daemon's automatic-mode child runs (`python -m verifier.auto_search JOB.json`): the
    preflight, or the interim choice (mode "interim": the strongest candidate within the budget on
    the first files, measured without SfM), so the daemon itself never poisons or measures."""

    images: list[tuple[str, str]]  # (source file, name in the dataset)
    out_dir: str
    result: str  # where the child writes the AutoDecision (or {"error": ...}) as JSON
    ladder: list[LadderEntry] | None = None  # None: poisoner.ladder's
    budget: VisibilityBudget = msgspec.field(default_factory=VisibilityBudget)
    options: PreflightOptions = msgspec.field(default_factory=PreflightOptions)
    exclude: list[str] = []  # candidate names left out (already found wanting)
    mode: Literal["preflight", "interim"] = "preflight"
