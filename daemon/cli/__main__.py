"""`python -m daemon.cli ...`: the `ppd` console script without installing it."""

from daemon.cli import app

app()
