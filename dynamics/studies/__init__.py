"""Numerical studies on the library: work-precision, where explicit methods fail, and the
Python-source baseline. The library never imports this package."""
