"""jaxflex: differentiable elastodynamics and trajectory design for a flexible five-bar robot."""
__version__ = "0.2.0"
