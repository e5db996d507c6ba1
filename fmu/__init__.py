"""FMUs: export (FMI 2.0 and 3.0 Model Exchange and Co-Simulation in one archive, from the
flattened model's generated C and the project's own FMI wrapper; docs/fmu.md), safe
loading of untrusted archives, a co-simulation master, and Model Exchange FMUs joined to the
CasADi model (docs/cosim.md)."""

from .archive import FmuArchiveError, open_fmu
from .cosim import Connection, CosimError, cosimulate
from .export import Experiment, FmuError, export_fmu
from .me_import import Composed, ImportedFMU, compose, import_me
from .participants import FmuParticipant, NativeParticipant, ParticipantError

__all__ = [
    "Composed",
    "Connection",
    "CosimError",
    "Experiment",
    "FmuArchiveError",
    "FmuError",
    "FmuParticipant",
    "ImportedFMU",
    "NativeParticipant",
    "ParticipantError",
    "compose",
    "cosimulate",
    "export_fmu",
    "import_me",
    "open_fmu",
]
