"""Is a folder inside a cloud-sync folder? A sync client would upload the outbox's originals
before ppd has poisoned them (and the vault would be synced too if it sat there), so
`ppd status` warns. Detection by the markers each client leaves in its folder's root."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class SyncFolder:
    client: str
    root: Path
    marker: str


# (client, marker name in the synced root, marker is a glob pattern)
_MARKERS: tuple[tuple[str, str], ...] = (
    ("Dropbox", ".dropbox"),
    ("Dropbox", ".dropbox.cache"),
    ("Syncthing", ".stfolder"),
    ("Nextcloud/ownCloud", ".sync_*.db"),
    ("Nextcloud/ownCloud", "._sync_*.db"),
    ("Nextcloud/ownCloud", ".owncloudsync.log"),
    ("Google Drive", ".tmp.drivedownload"),
    ("Google Drive", ".shortcut-targets-by-id"),
    ("OneDrive", ".odrive"),
    ("iCloud Drive", ".icloud"),
)
# Folder names the clients use for their root by default.
_ROOT_NAMES: tuple[tuple[str, str], ...] = (
    ("Dropbox", "Dropbox"),
    ("OneDrive", "OneDrive"),
    ("Google Drive", "Google Drive"),
    ("Google Drive", "My Drive"),
    ("Nextcloud/ownCloud", "Nextcloud"),
    ("iCloud Drive", "com~apple~CloudDocs"),
)


def find_sync_folder(path: Path) -> SyncFolder | None:
    """The sync folder that contains path (path itself or an ancestor), if any."""
    path = Path(path).expanduser().absolute()
    for folder in (path, *path.parents):
        for client, pattern in _MARKERS:
            try:
                hit = next(iter(folder.glob(pattern)), None)
            except OSError:
                hit = None
            if hit is not None:
                return SyncFolder(client=client, root=folder, marker=hit.name)
        for client, name in _ROOT_NAMES:
            if folder.name == name or (name == "OneDrive" and folder.name.startswith("OneDrive")):
                return SyncFolder(client=client, root=folder, marker=f"folder named {folder.name!r}")
    return None


def sync_warning(outbox: Path) -> str | None:
    """The one line that says the outbox is synced, so originals may be uploaded before ppd patches
    them (None: not synced). `ppd status`, `ppd watch` and `ppd service install` say the same."""
    sync = find_sync_folder(outbox)
    if sync is None:
        return None
    return (
        f"the outbox {outbox} is inside a {sync.client} folder ({sync.root}): originals may be uploaded "
        "before ppd patches them; keep the outbox out of synced folders"
    )
