"""cellctl: cell controller for robotic installation of large planar workpieces."""

__version__ = "0.1.0"
