"""Speed and memory figures. Each module is runnable alone (`python -m benchmarks.NAME`) and
prints a table; `python -m benchmarks` runs them all. Never timed inside the test suite."""
