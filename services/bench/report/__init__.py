"""The fidelity report: a session's raw-sensor statistics beside the paper's (fidelity), read
back from its MCAP file (data)."""
