"""The numerics of time-domain simulation: settings and the method registry (a leaf), one
module per method family, the stability guard of explicit methods, and ``simulate``."""
