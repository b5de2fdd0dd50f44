"""planar-pose training side: geometry, synthetic data, CNN training, evaluation and export.

Modules that need torch import it themselves; importing this package does not.
"""
