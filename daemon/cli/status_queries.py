"""What `ppd status`, `ppd dataset show` and `ppd poison`'s summary say about a dataset, read
from the store: counts, the newest verdict per attacker profile, a regression, the spec."""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from daemon.cli.errors import die, file_reason
from verifier.verdict import Verdict

if TYPE_CHECKING:
    from daemon.context import AppContext
    from daemon.datasets.folder_count import FolderCount
    from poisoner.spec import PatchSpec


def spec_summary(spec: PatchSpec) -> str:
    def length(v: int | float) -> str:
        return f"{v * 100:g}%" if isinstance(v, float) and v < 1 else f"{v:g}px"

    text = f"{spec.pattern} {length(spec.patch_size)} block {length(spec.block_size)} α{spec.alpha:g}"
    text += f" Δc{spec.contrast} {spec.position}"
    if any(spec.offset):
        text += f" +({length(spec.offset[0])}, {length(spec.offset[1])})"
    if spec.moves:
        text += f" {spec.motion} {length(spec.motion_step)}/image"
    if spec.lanes > 1:
        text += f" in {spec.lanes} lanes"
    if spec.ratio < 1:
        text += f" ratio {spec.ratio:g}"
    # a lanes mark's squares stay within the visibility budget: a patch_size above it changes nothing
    # on a 4:3 photo, which `dataset set --patch-size 8.5%` recorded in silence (a black-box review)
    if (capped := spec.capped_side(4000, 3000)) is not None:
        text += f"; squares capped at {capped[1] / 4000:.1%} of a 4:3 photo's width by the visibility budget"
    return text


def age(ts: float) -> str:
    seconds = max(0.0, time.time() - ts)
    for unit, size in (("d", 86400), ("h", 3600), ("m", 60)):
        if seconds >= size:
            return f"{seconds / size:.0f}{unit} ago"
    return f"{seconds:.0f}s ago"


def regression_of(runs: list[dict[str, Any]]) -> dict[str, Any] | None:
    """The newest run per profile that went protected → not_protected since its previous run."""
    by_profile: dict[str, list[dict[str, Any]]] = {}
    for run in runs:  # newest first
        by_profile.setdefault(run["profile"], []).append(run)
    for profile_runs in by_profile.values():
        if len(profile_runs) >= 2:
            latest, previous = profile_runs[0], profile_runs[1]
            if previous["verdict"] == Verdict.PROTECTED and latest["verdict"] == Verdict.NOT_PROTECTED:
                return latest
    return None


def latest_by_profile(runs: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """The newest verdict of each profile (daemon.states.newest_per_profile), with the number it rests on."""
    from daemon.states import newest_per_profile, run_left_out

    return {
        profile: {
            "verdict": run["verdict"],
            "frac_within_5deg": ((run.get("metrics") or {}).get("vs_clean") or {}).get("frac_within_5deg"),
            "finished_at": run["finished_at"],
            "error": run["error"],
            "left_out": run_left_out(run),  # photos its COLMAP did not read: not measured
        }
        for profile, run in newest_per_profile(runs).items()
    }


def failures_phrase(name: str, counts: dict[str, int], files: int, not_reprotected: int = 0) -> str | None:
    """`1 of 5 patched, 4 failed (`ppd status B --failed`)`: what a headline leads with when files
    failed (it read "patched, not verified" with 4 of 5 failed: a black-box review); None when none."""
    import shlex

    from daemon.states import patched_count

    bad = [f"{counts[k]} {k}" for k in ("failed", "quarantined") if counts.get(k, 0)]
    done = f"{patched_count(counts)} of {files} patched, " if bad else ""
    if not_reprotected:  # patched, a re-protect failed on them (still their earlier mark)
        bad.append(f"{not_reprotected} not re-protected")
    return f"{done}{', '.join(bad)} (`ppd status {shlex.quote(name)} --failed`)" if bad else None


def protection_line(ctx: AppContext, name: str) -> str:
    """`NAME: what it is now: what to run next`, from the counts and each profile's verdict; led by
    the files that failed, if any; never "protected" while a file is left without the mark (the
    store's count of them: daemon.states.published_protection)."""
    from daemon.datasets.folder_count import restored_in_place, unprotected_phrases
    from daemon.states import Protection, dataset_protection, next_step, patched_count, published_protection

    counts = ctx.store.counts(name)
    protection, profiles = dataset_protection(
        counts, latest_by_profile(ctx.store.current_verification_runs(name, limit=50))
    )
    step = next_step(protection, name)
    root = (ctx.store.dataset(name) or {}).get("root")
    unmarked = unprotected_phrases(
        counts, restored_in_place(ctx, name, root) if root and counts.get("restored") else 0
    )
    shown = published_protection(protection, profiles, unmarked, patched_count(counts))[2]
    now = shown + (f": {step}" if step else "")
    files = counts.get("files", 0) - counts.get("removed", 0)  # a removed row's file is no longer there
    failures = failures_phrase(name, counts, files, len(ctx.store.not_reprotected(name)))
    if failures is None:
        return f"{name}: {now}"
    if protection is Protection.NOTHING_PATCHED:  # "0 of 4 patched" says it
        return f"{name}: {failures}"
    if protection is Protection.PATCHED_NOT_VERIFIED:  # "patched" is said already
        now = "not verified" + (f": {step}" if step else "")
    return f"{name}: {failures}; {now}"


def _protection(
    counts: dict[str, int], verdicts: dict[str, dict[str, Any]], name: str, unmarked: list[str]
) -> dict[str, Any]:
    """The dataset's protection as published (daemon.states.published_protection): "state", "profiles"
    and "text" count its files left without the mark (unmarked: unprotected_phrases); "patched_files"
    is what the verifications measured on the patched ones, and "next" follows from it."""
    from daemon.states import (
        dataset_protection,
        next_step,
        patched_count,
        protection_text,
        published_protection,
        unmarked_decide,
    )

    measured, profiles = dataset_protection(counts, verdicts)
    state, shown, text = published_protection(measured, profiles, unmarked, patched_count(counts))
    return {
        "state": state.value,
        "profiles": shown,
        "text": text,
        "next": next_step(measured, name),
        # the files that made it NOT protected whatever the verdict ([] when the verdict is the dataset's)
        "unmarked": unmarked if unmarked_decide(measured, unmarked) else [],
        "patched_files": {
            "state": measured.value,
            "profiles": profiles,
            "text": protection_text(measured, profiles),
        },
    }


def _last_verification(latest: dict[str, Any] | None) -> dict[str, Any] | None:
    if latest is None:
        return None
    return {
        "profile": latest["profile"],
        "verdict": latest["verdict"],
        "finished_at": latest["finished_at"],
        "age_s": round(time.time() - latest["finished_at"], 1),
        "error": latest["error"],
    }


def _where(ctx: AppContext, root: str) -> str:
    """What a dataset's files are published with: the outbox (a sync publishes it whole), or its folder."""
    return "the outbox" if Path(root).is_relative_to(ctx.paths.outbox) else "the folder"


def _masks_missing(ctx: AppContext, name: str) -> str | None:
    """The dataset's subject-mask folder (the config's or the remembered one) when it is not there now."""
    from daemon.datasets.subject_masks import missing_mask_folder

    gone = missing_mask_folder(ctx, name)
    return str(gone.folder) if gone is not None else None


def _moved_into(ctx: AppContext, name: str, folder: FolderCount) -> dict[str, Any]:
    """Where a dataset's gone folder went (FolderCount.to_dict keys): moved_to as seen beside it, and
    moved_to_dataset, the other dataset that holds its files now: the user ran `ppd poison NEWFOLDER`,
    which made a dataset of it (then its rows were carried there, moved away), and status repeated the
    advice that led there (a black-box review). Said while the files there are patched: once restored
    there (`ppd restore NEWNAME`) "its patched files are in ..." stayed, no longer true (F15)."""
    from daemon.cli.targets import same_folder
    from daemon.states import PATCHED_VALUES, FileState

    seen = folder.to_dict()
    if folder.exists:
        return {**seen, "moved_to_dataset": None}
    if folder.moved_to is not None:
        to = folder.moved_to
        holders = [d["name"] for d in ctx.store.datasets()
                   if d["name"] != name and d["root"] and same_folder(Path(d["root"]), to)]  # fmt: skip
        return {**seen, "moved_to_dataset": holders[0] if holders else None}
    for row in ctx.store.files(name, state=FileState.REMOVED)[:MOVED_PROBE_ROWS]:  # a few: status stays quick
        to = (ctx.store.last_event(row["path"], "moved_away") or {}).get("detail", {}).get("to")
        now = ctx.store.file(to) if to else None
        patched_there = now is not None and now["state"] in PATCHED_VALUES and now["dataset"] != name
        other = ctx.store.dataset(now["dataset"]) if now is not None and patched_there else None
        if other is not None:
            return {**seen, "moved_to": other["root"], "moved_to_dataset": other["name"]}
    return {**seen, "moved_to_dataset": None}


def _quarantined_unrecorded(ctx: AppContext, root: str | None, counts: dict[str, int]) -> list[Path]:
    """The dataset's quarantined files whose names are not UTF-8 (no row: the quarantine folder says
    them), counted quarantined and among its files, as a recorded quarantined file is (F7)."""
    from daemon.protect.quarantine import unrecorded_quarantined
    from daemon.states import FileState

    held = unrecorded_quarantined(ctx, Path(root)) if root else []
    if held:
        counts[FileState.QUARANTINED.value] = int(counts.get(FileState.QUARANTINED.value, 0)) + len(held)
        counts["files"] = int(counts.get("files", 0)) + len(held)
    return held


# _moved_into reads this many of a gone folder's moved-away rows' events
MOVED_PROBE_ROWS = 3


def dataset_status(ctx: AppContext, name: str) -> dict[str, Any]:
    """Everything `ppd status NAME --json` says about one dataset. Its counts are the rows' and
    the folder's: files no row mentions (a run stopped half-way) are "untracked" and counted in
    "files"; "resume" says what finishes the dataset."""
    from daemon.datasets.folder_count import (
        current_counts,
        dataset_folder,
        not_patched_yet,
        restored_in_place,
        resume_command,
        unprotected_phrases,
    )
    from daemon.datasets.sealed_files import sealed_phrase
    from daemon.protect.mark_notes import mark_note_lines
    from daemon.states import left_out_photos, patched_count
    from daemon.verification.auto_mode import status_text as auto_status_text  # light: no torch, no pycolmap
    from daemon.verification.verify_state import running_verification  # light: msgspec and a small JSON file
    from verifier.verdict import HEADLINE_PROFILES

    row = ctx.store.dataset(name)
    if row is None:
        raise die(f"no dataset {name!r}")
    spec = ctx.store.get_spec(row["spec_id"]) if row["spec_id"] else None
    runs = ctx.store.verification_runs(name, limit=50)
    regression = regression_of(runs)
    folder = dataset_folder(ctx, name, row["root"])
    counts = current_counts(ctx, name, folder)
    held = _quarantined_unrecorded(ctx, row["root"], counts)
    # only runs that measured the pixels as they are now make the verdict (issue 25); runs before
    # the last change stay in the history
    verdicts = latest_by_profile(ctx.store.current_verification_runs(name, limit=50))
    left = not_patched_yet(counts)
    restored = restored_in_place(ctx, name, row["root"]) if counts.get("restored") else 0
    return {
        "name": name,
        "root": row["root"],
        "folder": _moved_into(ctx, name, folder),
        "not_patched_yet": left,
        "not_patched_files": [str(f) for f in folder.untracked],  # the files of that count no row names
        "not_utf8_files": [str(f) for f in folder.not_utf8],  # no row can name them (F7)
        "quarantined_not_utf8": [str(f) for f in held],
        "resume": resume_command(name, folder) if left else None,
        "publish_dir": row["publish_dir"],
        "subject_masks": row.get("subject_masks"),  # remembered with the dataset (issue 25)
        "masks_missing": _masks_missing(ctx, name),  # its files wait for it: not "run `ppd poison`" (F1)
        "spec_id": row["spec_id"],
        "spec": spec.to_dict() if spec else None,
        "spec_summary": spec_summary(spec) if spec else None,
        "spec_lost": None if spec else ctx.store.lost_spec(name),  # its files' spec, a rebuild did not find
        "auto": auto_status_text(ctx, name),  # automatic mode's decision in force (None: not decided)
        "counts": counts,
        "restored_in_place": restored,
        # patched with another spec than the dataset's: a re-protect that failed or was killed half-way
        # left them (a black-box review: status said "patched 40" under the new spec, 33 had the old)
        "other_spec": ctx.store.patched_with_other_spec(name, row["spec_id"]),
        # patched files a re-protect failed on: their earlier mark kept; `--failed` says why
        "not_reprotected": len(ctx.store.not_reprotected(name)),
        # put back by a `ppd restore` stopped before it recorded them: said so, with the command that records
        "restored_unrecorded": [str(p) for p in folder.restored_unrecorded],
        # ppd's stale temporaries its sweep could not remove (daemon.datasets.folder_count.sweep_temps)
        "leftover_temps": [str(p) for p in folder.temps],
        # those it removed (a killed run's), said: status is the command a user runs to look
        "removed_temps": [str(p) for p in folder.temps_removed],
        # photos under names ppd does not patch, published with the folder (daemon.datasets.unpatched_names)
        "unpatched_names": [str(p) for p in folder.unpatched_names],
        "unpatched_where": _where(ctx, row["root"]),
        # symlinked folders in it, never followed, and their photos (daemon.datasets.linked_folders)
        "linked_folders": [link.to_dict() for link in folder.linked if link.photos],
        # ppd's output no row names, its seal verified: not "not patched yet" (daemon.datasets.sealed_files)
        "sealed_files": folder.sealed.to_dict(),
        "sealed_line": sealed_phrase(folder.sealed) or None,
        "patched": patched_count(counts),
        # where marks found no plain place, as `ppd poison` says it (issue 25): the daemon's files too
        "mark_notes": mark_note_lines(ctx.store.patched_place_notes(name)),
        "protection": _protection(counts, verdicts, name, unprotected_phrases(counts, restored)),
        # the configured attackers no current run measured: `--check` waits for them (it passed on
        # one profile of five; a black-box review)
        "profiles_not_verified": [
            p for p in ctx.config.verification.profiles if p in HEADLINE_PROFILES and p not in verdicts
        ],
        "last_verification": _last_verification(runs[0] if runs else None),
        "verdicts": verdicts,
        # photos a counted profile's COLMAP did not read: no verdict covers them (verifier.sfm_images)
        "not_measured": left_out_photos(verdicts),
        "verifying": running_verification(ctx.paths, name),  # a verification running now (issue 30)
        "regression": None
        if regression is None
        else {
            "profile": regression["profile"],
            "run_id": regression["id"],
            "finished_at": regression["finished_at"],
        },
    }


def unprotected_files(d: dict[str, Any]) -> list[str]:
    """`2 failed`, `5 restored by you`, ...: the files of a dataset_status report that carry no mark."""
    from daemon.datasets.folder_count import unprotected_phrases

    return unprotected_phrases(d["counts"], d.get("restored_in_place", 0))


def failed_files(ctx: AppContext, name: str) -> list[dict[str, Any]]:
    """Each file of a dataset that could not be patched, with its one-line reason (the store row's
    error): failed ones (still in place) and quarantined ones (moved out of the outbox: where to); then
    patched ones a re-protect failed on, and those not moved to the publish folder."""
    from daemon.states import FileState
    from daemon.store.datasets import natural_key

    listed = []
    for state in (FileState.FAILED, FileState.QUARANTINED):
        # x2 before x10, as `ppd poison` lists them (a black-box review read them sorted as text)
        for r in sorted(ctx.store.files(name, state=state.value), key=lambda r: natural_key(r["path"])):
            item = {"path": r["path"], "state": state.value, "reason": file_reason(r["path"], r.get("error"))}
            if state is FileState.QUARANTINED:  # where it went (the watch log said it; status did not)
                moved = ctx.store.last_event(r["path"], "quarantined")
                item["moved_to"] = (moved or {}).get("detail", {}).get("to")
            elif not Path(r["path"]).exists():  # an --out copy never written: the source to fix
                said = ctx.store.last_event(r["path"], "failed")
                item["source"] = (said or {}).get("detail", {}).get("source")
            listed.append(item)
    stuck = [{"path": r["path"], "state": r["state"], "reason": r["error"], "not_moved": True}
             for r in ctx.store.not_moved(name)]  # fmt: skip
    return listed + [_not_reprotected_item(ctx, r) for r in ctx.store.not_reprotected(name)] + stuck


def _not_reprotected_item(ctx: AppContext, row: dict[str, Any]) -> dict[str, Any]:
    """A patched file a re-protect failed on: not a failed file, as long as it still carries the mark
    ppd wrote (under its earlier spec); one changed since, maybe not protected, is said so."""
    from daemon.datasets.folder_count import changed_since_patched

    tried = (ctx.store.last_event(row["path"], "reprotect_failed") or {}).get("detail", {}).get("spec_id")
    to = f" to spec {tried}" if tried else ""
    reason = file_reason(row["path"], row["error"])
    if changed_since_patched(row):
        what = "changed since ppd patched it, maybe NOT protected"
    else:
        what = f"still carries the earlier spec's mark (spec {row['spec_id']})"
    said = f"{what}; not re-protected{to}: {reason}"
    return {"path": row["path"], "state": row["state"], "reason": said, "not_reprotected": True}


def print_running(report: list[dict[str, Any]]) -> None:
    """One line per dataset being verified now: `castle: verifying, 4 min, default 1/5: ...`."""
    from daemon.cli.output import console

    for d in report:
        running = d.get("verifying")
        if running:
            console().print(f"{d['name']}: {running['line']}", markup=False, soft_wrap=False)
