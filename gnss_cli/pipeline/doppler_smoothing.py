"""The former module of the ``smoother`` (:mod:`gnss_cli.pipeline.smoother`): the names other modules
import from here, until they import them from :mod:`gnss_cli.pipeline.measurements`."""

from gnss_cli.pipeline.measurements import factors_from_totals, free_misfit_totals, misfit_totals

__all__ = ["factors_from_totals", "free_misfit_totals", "misfit_totals"]
