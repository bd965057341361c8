"""The benchmark suite: ``python -m benchmarks --list``, ``python -m benchmarks NAME [options]``.

Each case is a module ``benchmarks/NAME.py`` with ``main(argv)``; results go to
``benchmarks/results/<name>.json`` in one schema (:mod:`benchmarks._common`). See benchmarks/README.md.
"""
