"""The lines under `ppd status`'s table: what to run next for each dataset. What leaves files
unprotected comes first; the routine advice many datasets share ("run `ppd verify NAME`") is one line
once more than a few datasets have it (23 such lines buried the ones that matter: a black-box review).

Light at import (`ppd status` loads it).
"""

from __future__ import annotations

import shlex
from pathlib import Path
from typing import Any

from daemon.cli.output import console, print_line
from daemon.states import Protection, next_step

# Ranks: a verdict that does not hold, then files left unprotected, then the routine next step.
URGENT, UNPROTECTED, ROUTINE = 0, 1, 2
# The protection states whose next step is routine: a verification to run, a report to read.
ROUTINE_STATES = frozenset({Protection.PATCHED_NOT_VERIFIED.value, Protection.UNVERIFIABLE.value})
GROUP_OVER = 3  # more datasets than this with the same routine step: one line names them
NAMES_SHOWN = 10  # a grouped line names this many, then says how many more


def next_step_lines(d: dict[str, Any]) -> list[str]:
    """What to run next for one dataset, the most urgent first."""
    return [line for _, line in sorted(ranked_steps(d), key=lambda item: item[0])]


def step_state(d: dict[str, Any]) -> str:
    """The state a dataset's next step follows from: its verification's, of the patched files (the
    files left unmarked beside them have their own lines)."""
    return str(d["protection"]["patched_files"]["state"])


def ranked_steps(d: dict[str, Any]) -> list[tuple[int, str]]:
    """(rank, line) for one dataset: its failures, finishing an interrupted run (verifying half a
    dataset says nothing about the rest), else the protection's next step; then what else leaves
    files unprotected. A stable sort by rank keeps this order within a rank."""
    from daemon.cli.status_queries import failures_phrase
    from daemon.datasets.folder_count import resume_line

    c, name, steps = d["counts"], d["name"], []
    # a re-protect's failures were said once, then nowhere (a black-box review)
    failures = failures_phrase(name, c, c.get("files", 0), d.get("not_reprotected", 0))
    if failures:
        steps.append((UNPROTECTED, f"{name}: {failures}"))
    resume = resume_line(c, d["resume"], d.get("masks_missing")) if d.get("resume") else None
    if resume:
        steps.append((UNPROTECTED, f"{name}: {resume}"))
    elif d["protection"]["next"]:
        rank = ROUTINE if step_state(d) in ROUTINE_STATES else URGENT
        steps.append((rank, f"{name}: {d['protection']['next']}"))
    return steps + [(UNPROTECTED, line) for line in _unprotected_lines(d)] + _spec_lost_steps(d)


def _spec_lost_steps(d: dict[str, Any]) -> list[tuple[int, str]]:
    """A dataset whose spec a `ppd store rebuild` did not recover: its new photos are refused until it is
    given back (daemon.store.datasets.spec_not_recovered)."""
    from daemon.store.datasets import spec_not_recovered

    if not d.get("spec_lost"):
        return []
    return [(UNPROTECTED, f"{d['name']}: {spec_not_recovered(d['name'], d['spec_lost'])}")]


def _unprotected_lines(d: dict[str, Any]) -> list[str]:
    """Files of the dataset that are not (or may not be) carrying the mark, and what to run."""
    c, name, lines = d["counts"], d["name"], []
    root = shlex.quote(str(d["root"]))
    if c.get("waiting"):
        lines.append(f"{name}: {c['waiting']} still being written (incomplete), NOT protected yet: the "
                     "daemon patches each once complete, or quarantines it if it stays so")  # fmt: skip
    if c.get("changed"):  # another size or time than ppd wrote: an original copied back, an edit
        lines.append(f"{name}: {c['changed']} changed since ppd patched them (size or time), maybe NOT "
                     f"protected now: `ppd poison {root}` checks them and patches what needs it")  # fmt: skip
    if c.get("renamed"):  # patched and here: only verify, which reads the rows' paths, misses them
        lines.append(f"{name}: {c['renamed']} patched file(s) renamed since, still carrying the mark: "
                     f"`ppd poison {root}` records their new names")  # fmt: skip
    if c.get("unprotectable"):  # a reconstruction reads them all the same (a black-box review)
        lines.append(f"{name}: {c['unprotectable']} photo(s) or video(s) in a format ppd cannot protect, "
                     "NOT protected: convert them to JPEG, PNG, WebP, HEIC, MP4 or a TIFF named .tif, "
                     "or move them out")  # fmt: skip
    if paths := d.get("unpatched_names"):  # the daemon leaves them; a sync publishes them (F4)
        from daemon.datasets.unpatched_names import unpatched_line

        lines.append(f"{name}: {unpatched_line(paths, d['unpatched_where'])}")
    if links := d.get("linked_folders"):  # never followed; a publisher that follows links ships them
        from daemon.cli.linked_lines import linked_status_line
        from daemon.datasets.linked_folders import LinkedFolder

        linked = linked_status_line([LinkedFolder.from_dict(x) for x in links], Path(d["root"]))
        lines += [f"{name}: {linked}"] if linked else []
    lines += _not_utf8_lines(d)
    if d.get("restored_in_place"):  # originals back where they are published: said in the overview
        # some still patched: a restore stopped part-way (killed) is finished by running it again (a
        # black-box review: only the re-patch was offered to a user who wanted every original back)
        rest = f"; `ppd restore {shlex.quote(name)}` restores the rest" if d.get("patched") else ""
        lines.append(f"{name}: {d['restored_in_place']} restored by you, NOT protected: "
                     f"`ppd poison {root} --force` patches them again{rest}")  # fmt: skip
    if d.get("other_spec"):
        lines.append(f"{name}: {d['other_spec']} patched with another spec than the dataset's (moved "
                     "in from another dataset, or a re-protect did not finish?): "
                     f"`ppd dataset set {shlex.quote(name)} --reprotect` gives them its spec")  # fmt: skip
    return lines + _stopped_run_lines(d)


def _not_utf8_lines(d: dict[str, Any]) -> list[str]:
    """Files whose names are not UTF-8: every run refuses them (the store cannot hold the name), so
    not "not patched yet: run `ppd poison`", which fails the same way each time; the daemon moves such a
    file of the outbox to the quarantine folder, which status never said (a black-box review, F7)."""
    from daemon.protect.job import shown_name, shown_path

    name, lines = d["name"], []
    if here := [Path(p) for p in d.get("not_utf8_files", [])]:
        lines.append(f"{name}: {len(here)} file(s) whose names are not UTF-8 ({_few(here, shown_name)}), "
                     "NOT protected: ppd cannot record such names: rename them, then `ppd poison` patches "
                     "them")  # fmt: skip
    if held := [Path(p) for p in d.get("quarantined_not_utf8", [])]:
        lines.append(f"{name}: {len(held)} file(s) whose names are not UTF-8 moved to the quarantine folder "
                     f"({_few(held, shown_path)}): ppd cannot record such names: rename them and move them "
                     "back into the outbox to protect them")  # fmt: skip
    return lines


def _few(paths: list[Path], shown: Any) -> str:
    return ", ".join(shown(p) for p in paths[:3]) + (", ..." if len(paths) > 3 else "")


def _stopped_run_lines(d: dict[str, Any]) -> list[str]:
    """What a `ppd restore` (or poison) killed mid-file left: originals back but not recorded (not
    "changed since patched": they hold the original's bytes), and its temporaries: those the sweep removed,
    those it could not."""
    name, lines = d["name"], []
    if restored := d.get("restored_unrecorded"):
        # which of the two put it back is not known: a user's copy must not be steered into staying
        # unprotected (`ppd restore` records it restored, which poison then leaves: a diff review)
        root = shlex.quote(str(d["root"]))
        command = f"ppd restore {shlex.quote(restored[0])}" if len(restored) == 1 else "ppd restore FILE"
        lines.append(f"{name}: {len(restored)} holding the original again (copied back, or a stopped `ppd "
                     f"restore`), NOT protected: `ppd poison {root}` protects them again; `{command}` "
                     "records them restored if that is what you meant")  # fmt: skip
    if temps := d.get("leftover_temps"):
        lines.append(f"{name}: {len(temps)} hidden temporary file(s) of a stopped ppd run, which ppd could "
                     f"not remove: delete them before the folder is published ({_shown(temps)})")  # fmt: skip
    if removed := d.get("removed_temps"):
        lines.append(f"{name}: removed {len(removed)} temporary file(s) a killed ppd left: {_shown(removed)}")
    return lines


def _shown(paths: list[str], most: int = 3) -> str:
    """The first few paths, shell-quoted, `, ...` when there are more."""
    return ", ".join(shlex.quote(p) for p in paths[:most]) + (", ..." if len(paths) > most else "")


def step_lines(report: list[dict[str, Any]]) -> list[str]:
    """Every dataset's lines, the most urgent first (datasets in the report's order within a rank);
    a routine step more than GROUP_OVER datasets share is one line."""
    ranked = [(rank, line, d) for d in report for rank, line in ranked_steps(d)]
    ranked.sort(key=lambda item: item[0])
    sharing: dict[str, list[str]] = {}
    for rank, _, d in ranked:
        if rank == ROUTINE:
            sharing.setdefault(step_state(d), []).append(d["name"])
    grouped = {state for state, names in sharing.items() if len(names) > GROUP_OVER}
    lines = [line for rank, line, d in ranked if rank != ROUTINE or step_state(d) not in grouped]
    return lines + [_grouped_line(state, sharing[state]) for state in sorted(grouped)]


def _grouped_line(state: str, names: list[str]) -> str:
    """`run `ppd verify NAME` for 23 datasets: set 1, set 2, ..., and 13 more`."""
    more = len(names) - NAMES_SHOWN
    shown = ", ".join(names[:NAMES_SHOWN]) + (f", and {more} more" if more > 0 else "")
    return f"{next_step(Protection(state), 'NAME')} for {len(names)} datasets: {shown}"


def print_next_steps(report: list[dict[str, Any]]) -> None:
    """Word-wrapped to the terminal (soft_wrap off): these lines say what to run next."""
    for line in step_lines(report):
        print_line(console(), line)
