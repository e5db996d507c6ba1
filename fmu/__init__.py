"""FMUs: export (FMI 2.0 and 3.0 Model Exchange and Co-Simulation in one archive, from the
flattened model's generated C and the project's own FMI wrapper; docs/fmu.md), safe
loading of untrusted archives and a co-simulation master (docs/cosim.md)."""

from .archive import FmuArchiveError, open_fmu
from .cosim import Connection, CosimError, cosimulate
from .export import Experiment, FmuError, export_fmu
from .participants import FmuParticipant, NativeParticipant, ParticipantError

__all__ = [
    "Connection",
    "CosimError",
    "Experiment",
    "FmuArchiveError",
    "FmuError",
    "FmuParticipant",
    "NativeParticipant",
    "ParticipantError",
    "cosimulate",
    "export_fmu",
    "open_fmu",
]
