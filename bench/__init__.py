"""The benchmarks (`python -m bench [name]`), run from a checkout."""

import os
from pathlib import Path

# ppd finds the shared datasets only where it is told (verifier/shared_data.py); the benches run
# from a checkout with ../shared beside it.
os.environ.setdefault("PPD_SHARED_DATA", str(Path(__file__).resolve().parents[2] / "shared" / "datasets"))
