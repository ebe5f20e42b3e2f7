"""The tracking filter proper: error-state layout, parameters, numba kernels (`kernels/`),
measurement models (`models/`), pose maps and the filter. Pure numpy/numba: no protobuf, no
files, no bus."""
