"""ppd's application side: the CLI, the provenance store, the originals vault and the watcher."""
