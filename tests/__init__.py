"""ppd's test suite: a package, so import-linter holds it to its contracts (testkit yes, bench never)."""
