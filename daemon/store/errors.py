"""The store's exceptions: each carries one line that says what to do."""

from __future__ import annotations

from poisoner.errors import ExitStatus, PpdError


class StoreError(PpdError, RuntimeError):
    """A store operation that cannot be done as asked (message = one line)."""

    exit_status = ExitStatus.ENVIRONMENT


class StoreDamaged(StoreError):
    """The store file is not a usable SQLite database; `ppd store rebuild` rebuilds it."""


class PatchedNotFailed(StoreError):
    """A FAILED was about to overwrite a PATCHED row whose file is, in fact, the patched output."""


class DatasetSpecLocked(StoreError):
    """The dataset already has patched files under its spec; changing it needs --reprotect."""


class SpecNotRecovered(DatasetSpecLocked):
    """A dataset whose patched files carry a spec the store lost (`ppd store rebuild` found it nowhere):
    no new file of it is patched with another spec until `ppd dataset set` gives it back."""


class StoreTooNew(StoreError):
    """The store was made by a newer ppd (a schema version this one does not know): never migrated down."""
