"""One package per process. No service imports another service's package: they share only
`proto/` (as `tiplog.v1`) and the `tiplog` library."""
