"""Design studies: sweeps, Monte Carlo and global sensitivity over a transient scene.

A study (``[study]`` in a scene TOML, or a study TOML naming a ``base`` scene) is read and
checked by :mod:`.spec`, its sample points made by :mod:`.designs`, each sample simulated
and reduced to named metrics by :mod:`.evaluate` (with :mod:`.metrics`); batches run on
Dask by :mod:`.engine` into a resumable Zarr store (:mod:`.store`), driven by
:class:`.study.Study`. Heavy libraries (dask, xarray, zarr, SALib) are imported only
inside the functions that need them.
"""

from importlib import resources


def packaged_studies() -> dict:
    """Studies shipped with the package (``studies/*.toml``): name -> resource, sorted by
    name; light (no model, no CasADi), for listings."""
    root = resources.files(__name__) / "studies"
    found = {p.name.removesuffix(".toml"): p for p in root.iterdir() if p.name.endswith(".toml")}
    return dict(sorted(found.items()))
