"""A design study from its file to its Dataset: ``Study.from_file(path).run(out)``.

:meth:`Study.run` checks the sample count and the store's size against their caps and the
``out`` folder before any work, opens (or makes) the study's Zarr store, computes what it
does not hold yet on Dask (:mod:`.engine`) and returns the results as an xarray Dataset,
reshaped to the grid's axes for grid studies, after writing the figures and
``summary.json`` beside the store (:func:`.outputs.write_outputs`).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from sarcomere.dynamics.errors import ParameterError

from ..catalog import version
from .store import (
    Column,
    StoreError,
    StudyStore,
    check_out_folder,
    estimated_bytes,
    locked,
    series_name,
)

#: Default cap on the store's estimated (uncompressed) size [bytes].
MAX_STORE_BYTES = 2 * 1024**3


class Study:
    """A loaded, validated study definition (``spec.StudyDef``) that can be run."""

    def __init__(self, definition) -> None:
        self.definition = definition

    @classmethod
    def from_file(cls, path: str | Path, parameters: str | Path | None = None) -> Study:
        """Load and validate the study in ``path`` (a study TOML, a scene TOML with a
        ``[study]`` section, or a packaged study's name); ``parameters``: a parameter file
        included after the scene's (``--parameters FILE``)."""
        from .spec import load_study

        return cls(load_study(path, parameters))

    def run(
        self,
        out: str | Path,
        workers: int | None = None,
        scheduler: str | None = None,
        progress: bool = True,
        *,
        max_samples: int | None = None,
        max_store_bytes: int = MAX_STORE_BYTES,
        evaluate=None,
        outputs: bool = True,
        plots: bool = True,
    ):
        """Compute the study's missing samples into ``out/study.zarr`` and return them.

        Parameters
        ----------
        out : path
            Results folder: new, empty, or holding this study's store (resumed).
        workers : int, optional
            Worker processes of the embedded cluster (default: the usable CPUs).
        scheduler : str, optional
            ``tcp://HOST:PORT`` of an existing Dask scheduler (instead of ``workers``).
        progress : bool
            Progress line (samples done, failures, rate, time left) on a terminal.
        max_samples : int, optional
            Cap on the sample count (default: the study's ``max_samples``).
        max_store_bytes : int
            Cap on the store's estimated uncompressed size [bytes].
        evaluate : callable, optional
            ``evaluate(study, indices, points) -> BatchResult``, picklable (default
            ``evaluate.evaluate_batch``); ``points`` are the batch's design rows.
        outputs : bool
            Write ``summary.json`` beside the store (``outputs.py``), and the figures if
            ``plots``; nothing when they are there for the same results already.
        plots : bool
            Draw the figures.

        Returns
        -------
        xarray.Dataset
            Per sample (dims ``sample``) or, for grids, on the grid's axes.
        """
        from .engine import check_cluster_arguments

        check_cluster_arguments(workers, scheduler)
        study = self.definition
        design = study.design()
        n = len(design.points)
        self._check_size(n, max_samples, max_store_bytes)
        path = check_out_folder(Path(out))
        with locked(Path(out)):
            store = StudyStore.open_or_create(path, **self._layout(design, study.batch))
            if evaluate is None:
                from .evaluate import evaluate_batch as evaluate
            from .engine import run_study

            run_study(
                evaluate,
                study,
                store,
                workers=workers,
                scheduler=scheduler,
                progress=progress,
                points=design.points,
            )
            return self._results(store, design, Path(out) if outputs else None, plots)

    def replot(self, out: str | Path, plots: bool = True):
        """Write the figures (if ``plots``) and ``summary.json`` again from the study's
        store in ``out``, computing nothing; the Dataset as :meth:`run` returns it."""
        study, out = self.definition, Path(out)
        path = check_out_folder(out)
        if not path.exists():
            raise StoreError(f"--out: {out} holds no {path.name}: nothing to plot")
        with locked(out):
            store = StudyStore.open(path, study.definition(), study.fingerprint())
            return self._results(store, study.design(), out, plots, force=True)

    def _results(self, store, design, out: Path | None, plots: bool, force: bool = False):
        ds = store.read()
        if design.grid_shape is not None:
            ds = to_grid(ds, design.factor_names, design.grid_shape)
        if out is not None:
            from .outputs import write_outputs

            write_outputs(ds, self.definition, out, draw=plots, force=force)
        return ds

    # -- checks and layout ----------------------------------------------------------------
    def _series(self) -> tuple[tuple[str, ...], np.ndarray | None]:
        series = self.definition.series
        if series is None:
            return (), None
        return tuple(series.signals), np.asarray(series.time, dtype=np.float64)

    def _check_size(self, n: int, max_samples: int | None, max_store_bytes: int) -> None:
        study = self.definition
        cap = study.max_samples if max_samples is None else max_samples
        if n > cap:
            raise ParameterError(
                "max_samples",
                cap,
                f">= {n} for study '{study.name}' ({n} samples); raise [study] max_samples "
                "or --max-samples",
            )
        signals, time = self._series()
        points = len(signals) * (0 if time is None else time.size)
        size = estimated_bytes(n, len(study.factors), len(study.metrics), points)
        if size > max_store_bytes:
            raise ParameterError(
                "max_store_bytes",
                max_store_bytes,
                f">= {size} for study '{study.name}' ({n} samples x "
                f"{size // n} B estimated = {size / 1e6:.1f} MB); raise --max-store-mb",
            )

    def _layout(self, design, batch: int | None) -> dict:
        from .engine import default_batch
        from .spec import signal_unit

        study = self.definition
        signals, time = self._series()
        known = {f.name: f for f in study.factors}
        factors = [
            (_factor_column(known.get(name), name), design.points[:, i])
            for i, name in enumerate(design.factor_names)
        ]
        attrs = {
            "base": str(study.base),
            "kind": study.kind,
            "method": design.method,
            "seed": study.seed,
            "version": version(),
        }
        if design.grid_shape is not None:
            attrs["grid_factors"] = json.dumps(list(design.factor_names))
        n = len(design.points)
        return dict(
            definition=study.definition(),
            fingerprint=study.fingerprint(),
            factors=factors,
            metrics=[Column(m.name, m.unit, m.long_name) for m in study.metrics],
            series=[
                Column(series_name(s), signal_unit(study, s), f"{s} over time") for s in signals
            ],
            series_time=time,
            chunk=batch or default_batch(n),
            attrs=attrs,
        )


def _factor_column(factor, name: str) -> Column:
    if factor is None:
        return Column(name, "1", name)
    return Column(name, factor.unit, getattr(factor, "long_name", "") or name)


def to_grid(ds, factor_names, grid_shape):
    """``ds`` (dims ``sample``) on the grid's axes: one dimension per factor (C order of
    the samples), the factor values as coordinates."""
    import xarray as xr

    shape = tuple(int(s) for s in grid_shape)
    names = list(factor_names)
    points = np.stack([ds[name].values for name in names], axis=-1).reshape(*shape, len(names))
    coords = {}
    for axis, name in enumerate(names):
        index = [0] * len(names)
        index[axis] = slice(None)
        coords[name] = (name, points[(*index, axis)], ds[name].attrs)
    variables = {}
    for var_name, var in ds.data_vars.items():
        if var_name in names:
            continue
        rest = var.dims[1:]
        variables[var_name] = (
            (*names, *rest),
            var.values.reshape(*shape, *var.shape[1:]),
            var.attrs,
        )
    extra = {k: v for k, v in ds.coords.items() if "sample" not in v.dims}
    return xr.Dataset(variables, coords={**coords, **extra}, attrs=ds.attrs)
