"""Polyhedral geometry: polytope operations and LPs (``polytope``), vertex enumeration,
point location in a partition (``locate``) and the compiled kernels they share."""
