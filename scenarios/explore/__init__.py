"""Design studies: sweeps, Monte Carlo and global sensitivity over a transient scene.

A study (``[study]`` in a scene TOML, or a study TOML naming a ``base`` scene) is read and
checked by :mod:`.spec`, its sample points made by :mod:`.designs`, each sample simulated
and reduced to named metrics by :mod:`.evaluate` (with :mod:`.metrics`). Heavy libraries
(dask, xarray, zarr, SALib) are imported only inside the functions that need them.
"""
