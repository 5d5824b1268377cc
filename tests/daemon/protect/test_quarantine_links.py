"""A symlink leaves the outbox as a link, on any filesystem, its target never touched."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from daemon.protect.one_file import AppContext


@pytest.mark.skipif(not Path("/dev/shm").is_dir(), reason="needs a second filesystem (tmpfs at /dev/shm)")
@pytest.mark.parametrize("relative", [False, True])
def test_a_symlink_is_quarantined_across_filesystems_as_a_link(
    ppd_env: dict[str, Path], relative: bool
) -> None:
    """A diff review: with the quarantine folder on another filesystem, rename and link() fail
    (EXDEV) and the copy path refuses a symlink (O_NOFOLLOW: 'Too many levels of symbolic links'):
    the link stayed in the outbox. It is made again there, pointing where it pointed (a relative one
    made absolute), and its target is never opened or changed."""
    import tempfile

    from daemon.protect.quarantine import quarantine

    real = ppd_env["outbox"].parent / "elsewhere" / "real.jpg"
    real.parent.mkdir()
    real.write_bytes(b"\xff\xd8 an unprotected original")
    real.chmod(0o644)
    link = ppd_env["outbox"] / "shoot" / "link.jpg"
    link.parent.mkdir()
    link.symlink_to(os.path.relpath(real, link.parent) if relative else real)
    with tempfile.TemporaryDirectory(dir="/dev/shm") as other:
        (ppd_env["config"] / "config.toml").write_text(f'[daemon]\nquarantine_dir = "{other}"\n')
        ctx = AppContext.open()
        try:
            moved = quarantine(ctx, link, "shoot", "a symlink")
        finally:
            ctx.close()
        assert moved is not None and moved.is_symlink() and Path(os.readlink(moved)).is_absolute()
        assert moved.resolve() == real.resolve() and not link.is_symlink() and not link.exists()
    assert real.read_bytes() == b"\xff\xd8 an unprotected original" and (real.stat().st_mode & 0o777) == 0o644
