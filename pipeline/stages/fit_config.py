"""Configuration of the kinematic body-model fit (stage ``fit``): ``FitConfig``.

Defined in ``pipeline.backends.fitting.config``, next to the fit backends that take it (so
they do not import a stage module), and re-exported here for the stage.
"""

from pipeline.backends.fitting.config import FitConfig

__all__ = ["FitConfig"]
