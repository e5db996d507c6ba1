"""FMU export and import (next issues: FMI 2.0/3.0, Model Exchange and Co-Simulation from
the flattened model's generated C; fmpy as the reference importer). Nothing here yet."""
