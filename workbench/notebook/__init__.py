"""The notebook front end: :class:`Workbench`, a design panel in Jupyter (ipywidgets).

Needs the ``notebook`` extra (``pip install 'codev[notebook]'``: ipywidgets, rerun-notebook,
JupyterLab); see docs/notebooks.md.
"""

from workbench.notebook.panel import Workbench

__all__ = ["Workbench"]
