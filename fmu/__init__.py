"""FMU export: FMI 2.0 (and 3.0) Model Exchange and Co-Simulation in one archive, from the
flattened model's generated C and the project's own FMI wrapper (see docs/fmu.md)."""

from .export import Experiment, FmuError, export_fmu

__all__ = ["Experiment", "FmuError", "export_fmu"]
