"""volucal: volumetric calibration of 3-axis CNC machine tools."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("volucal")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0+unknown"
