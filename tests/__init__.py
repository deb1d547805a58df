"""palpa's tests, a package: shared helpers are imported as ``tests.procs`` etc."""
