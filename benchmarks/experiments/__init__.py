"""One-off quality experiments behind numbers in docs/ (each module says how to run it, what it prints)."""
