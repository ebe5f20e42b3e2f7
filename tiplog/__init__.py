"""tiplog: the common library shared by every service (bus, clock, configuration, geometry,
message registry, command line). Services import this and `tiplog.v1` (generated from
`proto/`), never each other."""

__version__ = "0.1.0"
