"""Closed-loop verification: ``verification`` (the verdict), the linear and nonlinear
reachability engines, interval arithmetic and plant enclosures, simulation, and the tube."""
