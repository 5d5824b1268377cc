"""`ppd store rebuild`: each dataset's spec back. A seal names only the spec's id (a hash of its content,
PatchSpec.spec_id), never its parameters, so the spec itself comes from where its content was kept: the
vault's `specs/` (Vault.keep_spec: every original kept since this ppd is kept with its spec), the old
store, an earlier store a rebuild kept aside, the config, or a named design in any corner (a design
chosen in the config gets its corner per dataset). A candidate is taken only when its content hashes to
the id, so none is ever mistaken for another. A dataset whose spec is found nowhere is named: the rebuild
exits 1 and the dataset refuses new photos until `ppd dataset set` gives the spec back
(daemon.store.datasets.spec_not_recovered), never taking the config's in silence (a black-box review).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterable, Iterator, Mapping
from typing import TYPE_CHECKING

from daemon.store.vault import Vault, VaultError
from poisoner.spec import POSITIONS, PatchSpec

if TYPE_CHECKING:
    from daemon.config import Config

HEX = frozenset("0123456789abcdef")


def recover_specs(
    vault: Vault, wanted: set[str], config: Config, stored: Iterable[tuple[str, Mapping[str, str]]]
) -> tuple[dict[str, PatchSpec], dict[str, str], list[str]]:
    """Each wanted spec id's PatchSpec, where it came from, and the ids found nowhere. stored: (where,
    {id: json}) of the stores that still give specs back (the old one, earlier ones kept aside), first
    first. A spec found elsewhere than the vault is kept there for next time."""
    found: dict[str, PatchSpec] = {}
    sources: dict[str, str] = {}
    missing: list[str] = []
    candidates: dict[str, tuple[PatchSpec, str]] | None = None  # made only when the vault lacks one
    for spec_id in sorted(i for i in wanted if i):
        kept = vault.load_spec(spec_id) if set(spec_id) <= HEX else None
        if kept is not None:
            found[spec_id], sources[spec_id] = kept, "vault"
            continue
        candidates = _candidates(config, stored) if candidates is None else candidates
        if spec_id in candidates:
            found[spec_id], sources[spec_id] = candidates[spec_id]
            with contextlib.suppress(OSError, VaultError):
                vault.keep_spec(found[spec_id])
        else:
            missing.append(spec_id)
    return found, sources, missing


def _candidates(
    config: Config, stored: Iterable[tuple[str, Mapping[str, str]]]
) -> dict[str, tuple[PatchSpec, str]]:
    """spec id -> (spec, where from), the first source of an id winning."""
    candidates: dict[str, tuple[PatchSpec, str]] = {}
    for where, specs in stored:
        for text in specs.values():
            with contextlib.suppress(ValueError, TypeError, KeyError):
                spec = PatchSpec.from_json(text)
                candidates.setdefault(spec.spec_id, (spec, where))
    for spec, where in _config_and_designs(config):
        candidates.setdefault(spec.spec_id, (spec, where))
        for corner in _corners(spec):
            candidates.setdefault(corner.spec_id, (corner, f"{where}, {corner.position}"))
    return candidates


def _config_and_designs(config: Config) -> Iterator[tuple[PatchSpec, str]]:
    """The config's specs (each configured dataset's, the [patch] one), the defaults, then every design a
    user can name (`--design`)."""
    from poisoner.ladder import design_specs

    for name in config.datasets:
        with contextlib.suppress(Exception):  # an automatic dataset's interim spec may not load here
            yield config.spec_for(name), "config"
    yield config.spec, "config"
    yield PatchSpec(), "defaults"
    for name, spec in design_specs().items():
        yield spec, f"design {name}"


def _corners(spec: PatchSpec) -> Iterator[PatchSpec]:
    """spec in each other position: a dataset's corner is judged on its photos when the config does
    not set one (daemon.datasets.subject_masks.place_corner)."""
    for position in POSITIONS:
        if position != spec.position:
            with contextlib.suppress(ValueError, TypeError):  # a position this kind of mark refuses
                yield spec.replace(position=position)
