"""The tracking filter proper: error-state layout, parameters, numba kernels, measurement
models, pose maps and the filter. Pure numpy/numba: no protobuf, no files, no bus."""
