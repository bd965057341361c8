"""Fleets of scans: the per-scan jobs (adapt, build, simulate) planned as tasks and run in local
processes or as Ray tasks, with a manifest that makes re-runs idempotent (a layer above ``jobs/``)."""
