"""Studies: reproducible comparisons of the papers (runnable modules)."""
