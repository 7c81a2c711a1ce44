"""volucal's Qt workbench (PySide6 + pyqtgraph): a thin skin over :mod:`volucal.core`."""
