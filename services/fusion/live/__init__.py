"""The live fusion service (`python -m services.fusion`): bus wiring, publishing, and the numba
warm-up done at install and start."""
