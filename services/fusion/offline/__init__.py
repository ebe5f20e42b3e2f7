"""The filter over a recorded session: reading a session's inputs (a library for the study and
the benchmarks too), `tiplog fusion run`, and the RTS smoother."""
