"""The study: run caches and sweeps, presets (the one home of defaults and budgets), figures, comparisons,
benchmarks and the book runner.  Nothing in the library imports this package."""
