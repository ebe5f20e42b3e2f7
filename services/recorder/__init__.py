"""Recorder: every topic into crash-safe MCAP files with embedded schemas."""
