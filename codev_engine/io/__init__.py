"""Files the engine writes and reads: atomic writes and checked ``.npz`` archives."""
