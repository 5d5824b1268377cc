"""A protected dataset verified: when (scheduler.py), the run and its records (verify.py), what
outlives a run (verify_state.py), automatic mode's state machine (auto_mode.py), the dataset's
report (dataset_report.py). Kept empty: nothing here loads pycolmap."""
