"""Performance suites: every row compares ours with a reference measured in the same run (``run_all`` runs
the quick ones; results in docs/performance.md)."""
