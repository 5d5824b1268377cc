"""Short CI versions of bench/bench_kill_loops.py: `ppd poison` (a real CLI process) SIGKILLed at
random instants and run again, and a deleted store followed by a second run and a restore."""

from __future__ import annotations

from pathlib import Path

import pytest

from bench.bench_kill_loops import poison_loop, store_deleted_round

pytestmark = pytest.mark.integration


def test_sigkilled_ppd_poison_then_run_again_loses_nothing_and_leaves_nothing(tmp_path: Path) -> None:
    result = poison_loop(tmp_path, kills=4, seed=3, per_kill=8, video_every=0)
    assert result["kills"] == 4
    assert result["findings"] == []
    for figure in ("invariants", "not_patched", "double", "not_restorable", "corrupt", "leftovers"):
        assert result[figure] == 0, (figure, result)


def test_store_deleted_no_double_poisoning_and_every_original_restored(tmp_path: Path) -> None:
    result = store_deleted_round(tmp_path, files=6, seed=1)
    assert result["poisoned twice (bytes changed by the second run)"] == 0
    assert result["originals not in the vault"] == 0
    assert result["restore exit non-zero"] == 0
    assert result["not restored to the original bytes"] == 0
    assert result["leftovers"] == 0
