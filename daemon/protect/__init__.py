"""One file protected: `one_file.protect_file` runs the stages (stages.py) in their crash-safe
order; many files in worker processes (pool.py); the poisoner isolated in a child (child.py, run
with `python -m daemon.protect.child`); files that cannot be patched leave the outbox
(quarantine.py); a lost store rebuilt from the vault and the seals (rebuild.py; what it carries
over from the old store: rebuild_carry.py). Kept empty: a module here loads only what it names."""
