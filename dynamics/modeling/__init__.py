"""The modelling language, with no physics and no solvers: variable records, ports,
components and their builder, flattening, and the flattened :class:`Model`."""
