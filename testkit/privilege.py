"""Running a ppd command as a user whom file modes bind: the tests run as root here, and root reads,
writes and removes anything unless its capability to override file modes is dropped."""

from __future__ import annotations

import os
import shutil

import pytest


def modes_bind() -> list[str]:
    """A command prefix under which file modes bind, root included (util-linux's setpriv drops the
    override capabilities); [] for a user they bind already. Skips the test when root has no setpriv."""
    if os.geteuid() != 0:
        return []
    setpriv = shutil.which("setpriv")
    if setpriv is None:
        pytest.skip("running as root without setpriv: file modes do not bind")
    caps = "-dac_override,-dac_read_search"
    return [setpriv, f"--inh-caps={caps}", f"--bounding-set={caps}", "--"]
