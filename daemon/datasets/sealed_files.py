"""ppd's output that no row of the store names: a file whose provenance seal verifies under this
installation's key over exactly its bytes (poisoner.provenance), found among the files `ppd status`
would otherwise call "not patched yet". After `ppd dataset forget NAME --force` on a published shoot
(its vault freed, its patched files still in the outbox), status called them "NOT protected, no dataset
holds yet" for good while `ppd watch` and `ppd poison` answered "unchanged (already ppd output)", so
`--check` could never pass again (a black-box review). They carry the mark: patched, not restorable
when the vault no longer keeps the original their seal names; the next run records the others.

A seal is checked as the daemon checks it (the tag over the whole file): a token copied onto another
photo, or left in an edited one, does not verify, and such a file stays "not patched yet".

Cheap, as `ppd status` must be: only files no row names are looked at; one with no token where ppd puts
it (the first or last MB: poisoner.provenance.read_seal_at_ends) costs at most those 2 MB, one with a
token a pass over it (about a sha256: ~1 GB/s). At most READ_BUDGET bytes per call; the files past it
stay "not patched yet" (the safe side: never called patched unchecked).
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

READ_BUDGET = 256 << 20  # bytes looked at per call (about 0.2 s warm)


@dataclass(frozen=True)
class Sealed:
    """Files no row names that are ppd's output, by whether the vault keeps their original."""

    kept: list[Path] = field(default_factory=list)  # the next `ppd watch` or `ppd poison` records them
    forgotten: list[Path] = field(default_factory=list)  # their original left the vault: not restorable

    @property
    def files(self) -> list[Path]:
        return sorted(self.kept + self.forgotten)

    def __len__(self) -> int:
        return len(self.kept) + len(self.forgotten)

    def to_dict(self) -> dict[str, list[str]]:
        return {
            "original_kept": [str(p) for p in self.kept],
            "original_forgotten": [str(p) for p in self.forgotten],
        }


def split_sealed(paths: Iterable[Path], data_dir: Path, vault_dir: Path) -> tuple[list[Path], Sealed]:
    """(the files that are not ppd's output, or were not checked, those that are). Without a seal key
    (none made yet) no file can be ppd's output of this installation."""
    from daemon.store.sealkey import load_key

    paths = list(paths)
    key = load_key(data_dir, create=False) if paths else None
    if not key:
        return paths, Sealed()
    from daemon.store.vault import VaultError, blob_path
    from poisoner.provenance import read_seal_at_ends

    rest: list[Path] = []
    sealed = Sealed()
    budget = READ_BUDGET
    for path in paths:
        seal = None
        if budget > 0:
            seal, looked = read_seal_at_ends(path, key)
            budget -= looked
        if seal is None:
            rest.append(path)
            continue
        try:
            kept = os.path.isfile(blob_path(vault_dir, seal.original_sha256))
        except VaultError:  # a seal naming no digest: its original cannot be kept
            kept = False
        (sealed.kept if kept else sealed.forgotten).append(path)
    return rest, sealed


def sealed_phrase(sealed: Sealed) -> str:
    """`25 file(s) carry ppd's mark, their originals forgotten: protected as patched, not restorable`
    (and those whose originals the vault keeps: a run records them)."""
    parts = []
    if sealed.forgotten:
        parts.append(f"{len(sealed.forgotten)} file(s) carry ppd's mark, their originals forgotten: "
                     "protected as patched, not restorable")  # fmt: skip
    if sealed.kept:
        parts.append(
            f"{len(sealed.kept)} file(s) carry ppd's mark with no record of them, their originals "
            "in the vault: protected as patched; `ppd watch` or `ppd poison` records them"
        )
    return "; ".join(parts)
