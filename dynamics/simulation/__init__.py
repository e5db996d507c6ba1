"""The numerics of time-domain simulation: settings and the method registry (a leaf), one
module per method family (``sundials``, ``fixed_step``, ``scipy_methods``), the stability
guard of explicit methods, the stepping ``Simulator`` and ``simulate`` on top of it."""
