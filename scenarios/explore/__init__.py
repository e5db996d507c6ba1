"""Design studies: grids, samples and global sensitivity over a scene, run on Dask.

A study (``[study]`` in a scene TOML) is loaded and validated by :mod:`.spec`, its points
made by :mod:`.designs`, evaluated in batches by :mod:`.evaluate`, run by :mod:`.engine`
into a Zarr store (:mod:`.store`) and driven by :class:`.study.Study`. Dask, xarray, Zarr
and SALib are imported only inside the functions that need them.
"""
