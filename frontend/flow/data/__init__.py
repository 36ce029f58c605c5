"""Flow training and evaluation data: file formats, standard dataset layouts, and data made here."""

from .sample import FlowSample

__all__ = ["FlowSample"]
