"""Pictures of results: notebook figures (matplotlib) and Rerun recordings. The only
modules of the engine that import matplotlib or rerun."""
