"""The outbox watched (the first room a dropped file enters): inotify events in (outbox.py), the
daemon's loop (watcher.py), what it counts and says per file (outcomes.py), its bounded queue
(workers.py), systemd's notify protocol (notify.py) and user unit (service.py), cloud-sync folders
told apart (syncdirs.py). Kept empty: `import daemon.watch.notify` must not load the rest."""
