"""The pixel tier: camera frames of the instrument over the phantom (renderer), with its exact
geometry (geometry), the instrument's drawing (instrument) and per-scene precomputation (scene)."""
