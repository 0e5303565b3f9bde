"""Tools: A/B timing of checkouts or runs, profiling a training step, and reading finished benchmark folders
back (merged seeds, the differences beyond the paper's claims)."""
