"""Studies only the benchmarks (and their tests) use, kept out of the installed package:
``python benchmarks/<name>.py`` imports them as ``studies.<module>``; the tests as
``benchmarks.studies.<module>`` (tests/conftest.py puts the repository root on the path)."""
