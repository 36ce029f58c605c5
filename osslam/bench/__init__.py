"""Batch benchmarks: suites of sequences x configs x repeats run as independent jobs, and their reports.

``suite`` (what to run) -> ``jobs`` (one run, recorded) -> ``executors`` (local process
pool or Ray) -> ``runner`` (skip finished jobs) -> ``collect``/``tables``/``render``/``plots``
-> ``report``.
"""
