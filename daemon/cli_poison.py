"""Compatibility name for tests/test_auto_daemon.py; the status queries live in
daemon.cli.status_queries (remove this file once that test imports from there)."""

from daemon.cli.status_queries import dataset_status

__all__ = ["dataset_status"]
