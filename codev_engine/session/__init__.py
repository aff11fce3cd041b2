"""Sessions: a design's spec, its journal and its cached stage artifacts in one folder."""
